"""The held-out benchmark (``cvxid bench --heldout``): draws, records, specs, failures, one run."""

import json

import numpy as np
import pandas as pd
import pytest

import cvxid.tools.heldout as heldout_module
from cvxid.app.cli import main
from cvxid.app.run import run
from cvxid.data.experiment import Experiment
from cvxid.identify.output_error import delay_standard_error, output_error
from cvxid.spec.load import load_problem
from cvxid.tools.heldout import (
    BASE_TERMS,
    EFFECTS,
    NOISES,
    TAU_RANGE,
    INPUT_DELAY_RANGE,
    X_RMS,
    by_duration,
    run_one,
    _falls,
    confusion,
    draw,
    heldout,
    summary,
    write,
)

EFFECT_TERMS = {"coulomb": "sign(x')", "quadratic_damping": "x'|x'|", "quadratic_stiffness": "x^2", "offset": "1",
                "stribeck": "sign(x')"}


def test_a_draw_is_reproducible_and_its_system_independent_of_the_noise_asked_for():
    first, again = draw(3, "coulomb", duration=6.0), draw(3, "coulomb", duration=6.0)
    assert first == again
    assert np.array_equal(first.experiment("train").output("x"), again.experiment("train").output("x"))
    other = draw(4, "coulomb", duration=6.0)
    assert other.tau != first.tau
    quiet, loud = draw(3, "none", noise=0.001, duration=6.0), draw(3, "none", noise=0.02, duration=6.0)
    assert (quiet.mass, quiet.coefficients, quiet.tau, quiet.train) == (loud.mass, loud.coefficients, loud.tau, loud.train)
    assert (quiet.noise, loud.noise) == (0.001, 0.02)


@pytest.mark.parametrize("effect", EFFECTS)
def test_drawn_parameters_lie_in_the_stated_ranges(effect):
    for seed in range(4):
        o = draw(seed, effect, duration=5.0)
        k = dict(o.coefficients)
        assert 0.5 <= o.mass <= 2 and 2 <= k["x"] <= 20 and 0.1 <= k["x'"] <= 1
        assert 0 < k.get("x^3", 1.0) <= 3
        assert 0.3 * k["x"] <= abs(o.gain) <= 0.5 * k["x"]
        assert TAU_RANGE[0] <= o.tau <= TAU_RANGE[1]
        assert o.noise in NOISES
        term = effect not in ("none", "input_delay")  # a late input adds no term
        assert (EFFECT_TERMS.get(effect) in k) == term
        assert len(o.coefficients) == 2 + ("x^3" in k) + term + (effect == "stribeck")  # Coulomb and its decay
        assert (INPUT_DELAY_RANGE[0] <= o.input_tau <= INPUT_DELAY_RANGE[1]) == (effect == "input_delay")
        assert o.train.kind in ("multisine", "chirp")
    o = draw(0, effect, duration=8.0)
    x = o.simulate("train")[1]
    assert X_RMS[0] <= np.sqrt(np.mean(x**2)) <= X_RMS[1]
    assert 0.3 * 0.85 <= np.std(x) <= 1.0 * 1.15  # the forcing scales x to its target


def test_record_lengths_are_drawn_in_5_to_200_s():
    lengths = [draw(seed).duration for seed in range(3)]
    assert all(5 <= d <= 200 for d in lengths) and len(set(lengths)) == 3


def test_records_start_mid_motion():
    for seed in range(5):
        o = draw(seed, duration=6.0)
        for which in ("train", "test"):
            t, x, v, _ = o.simulate(which)
            assert t[0] == 0.0 and np.allclose(np.diff(t), 1e-3)
            assert abs(x[0]) > 1e-3 * np.std(x) and abs(v[0]) > 1e-3 * np.std(v)
    assert o.train != o.test  # the test record has its own forcing and start


def test_the_written_spec_loads_with_the_true_terms(tmp_path):
    o = draw(2, "quadratic_damping", noise=0.01, duration=6.0)
    spec = load_problem(write(o, tmp_path / "structure"))
    assert spec.model.library.names == o.terms and "x'|x'|" in o.terms
    assert spec.model.delay.exact and spec.model.delay.gain is None
    assert spec.model.delay.tau_min <= TAU_RANGE[0] and spec.model.delay.tau_max >= TAU_RANGE[1]
    assert spec.model.nonnegative == ("x''",) and spec.fit.refine == "output_error" and spec.diagnose is None
    assert spec.truth.physical == pytest.approx(o.truth)  # (the gain too: the model estimates it)
    train = spec.experiment("train")
    assert train.time[0] == 0.0 and train.duration == pytest.approx(6.0)
    assert np.std(train.output("x") - o.simulate("train")[1]) == pytest.approx(0.01, rel=0.05)  # the noise
    assert spec.experiment("test").n > 0
    diagnosis = load_problem(write(o, tmp_path / "diagnosis", mode="diagnosis", known_gain=True))
    assert diagnosis.model.library.names == list(BASE_TERMS) and diagnosis.diagnose.refine
    assert diagnosis.model.delay.gain == pytest.approx(o.gain)


def test_a_failing_system_is_a_row_with_its_error(monkeypatch):
    class Result:
        polish = None  # no output-error fit: no delay limit

        def to_dict(self):
            return {"physical": {"m": 1.0, "x": 10.0, "x'": 0.5, "gain": 3.0, "tau": 0.1},
                    "tau": {"estimate": 0.1, "interval": [0.09, 0.11], "method": "output_error"}, "seconds": 0.5}

    def fake_run(path):
        if "heldout_1_" in path.read_text():
            raise RuntimeError("boom")
        return Result()

    monkeypatch.setattr(heldout_module, "run", fake_run)
    frame = heldout([0, 1], ["none", "bogus"], [0.01], duration=5.0, n_jobs=1)
    rows = frame.set_index(["seed", "effect"])
    assert len(rows) == 4
    assert rows.loc[(0, "none"), "status"] == "ok" and np.isfinite(rows.loc[(0, "none"), "tau error %"])
    assert rows.loc[(1, "none"), ["status", "error"]].tolist() == ["failed", "RuntimeError: boom"]
    assert rows.loc[(0, "bogus"), "error"].startswith("CvxidError: unknown hidden effect")
    table = summary(frame)
    assert table.loc[("none", 0.01), "systems"] == 2 and table.loc[("none", 0.01), "failures"] == 1
    assert table.loc[("bogus", 0.01), "failures"] == 2


def test_the_same_systems_at_two_lengths_are_paired():
    frame = pd.DataFrame({"seed": [0, 0, 1, 1, 2], "effect": "none", "noise": 0.01, "duration": [20.0, 200.0] * 2 + [20.0],
                          "tau error %": [1.0, -0.5, -0.2, 0.4, 3.0], "worst other %": [2.0, 1.0, 1.0, 1.0, 1.0],
                          "status": ["ok"] * 4 + ["failed"]})
    pairs = by_duration(frame)
    assert pairs[("|tau err| %", 200.0)].tolist() == [0.5, 0.4]
    assert pairs["longest at least as accurate"].tolist() == [True, False]


def test_the_command_refuses_a_spec_with_heldout_and_needs_one_without(tmp_path, capsys):
    assert main(["bench", "--heldout", str(tmp_path / "x.toml")]) == 2
    assert "give no SPEC" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["bench"])


@pytest.mark.parametrize("argv, said", [
    (["--heldout", "--long", "1e5"], "--heldout and --long are separate benchmarks: give one of them"),
    (["hidden_friction", "--seeds", "3"], "--seeds and --noises are for cvxid bench --heldout and --accuracy"),
    (["hidden_friction", "--keep", "k"], "--keep is for cvxid bench --heldout"),
    (["--heldout", "--duration", "-5"], "--duration takes record seconds like 8 or 20,200, each at least 1"),
    (["--heldout", "--noises", "-1"], "--noises takes noise levels like 0.01,0.001, each at least 0"),
    (["--heldout", "--effects", "none,bogus"], "--effects: unknown hidden effect 'bogus'; one of: none, coulomb"),
    (["--heldout", "--seeds", "1005:1000"], "--seeds 1005:1000 holds no seed"),
    (["hidden_friction"], "'hidden_friction' lists its terms: bench a spec with [model.library] order"),
    (["flexible_joint"], "'flexible_joint' is coupled"),
])
def test_bench_flags_that_would_be_ignored_or_fail_per_system_are_an_error_first(capsys, argv, said):
    """Each used to run (minutes of the held-out benchmark with a flag ignored, an empty
    table, an IndexError or the same error once per system) or to fail deep inside."""
    assert main(["bench", *argv]) == 2
    err = capsys.readouterr().err
    assert said in err and len(err.strip().splitlines()) == 1, err


TAU_TOLERANCE = 2.0
"""Percent, on 10 s records at noise 0.001 (two systems of the tuning range, true terms
given, gain estimated).  Loose: the README reports a few hundredths of a percent at this
noise on the paper's system; these two measured 0.87 % (seed 1) and 0.05 % (seed 4)."""


@pytest.mark.slow
def test_short_quiet_records_give_tau():
    frame = heldout([1, 4], ["none"], [0.001], duration=10.0, n_jobs=2)
    assert (frame["status"] == "ok").all(), frame["error"].tolist()
    assert frame["tau error %"].abs().max() < TAU_TOLERANCE, frame["tau error %"].tolist()
    # each structure-mode row carries its delay limit: the error in units of it is the same ratio
    assert (frame["tau limit %"] > 0).all(), frame["tau limit %"].tolist()
    assert np.allclose(frame["tau error / limit"], frame["tau error %"] / frame["tau limit %"])


def test_a_late_input_is_drawn_from_its_own_stream_and_written_into_the_spec(tmp_path):
    late, plain = draw(5, "input_delay", noise=0.01, duration=6.0), draw(5, "none", noise=0.01, duration=6.0)
    assert INPUT_DELAY_RANGE[0] <= late.input_tau <= INPUT_DELAY_RANGE[1] and plain.input_tau == 0.0
    assert (late.mass, late.coefficients, late.tau) == (plain.mass, plain.coefficients, plain.tau)
    assert late.truth["tau_u"] == late.input_tau and "tau_u" not in plain.truth
    _, x, _, f = late.simulate("train")
    _, x_plain, _, f_plain = plain.simulate("train")
    assert np.allclose(f / np.std(f), f_plain / np.std(f_plain))  # the same forcing, scaled to the same x RMS
    assert not np.allclose(x / np.std(x), x_plain / np.std(x_plain), atol=1e-3)  # received late
    spec = load_problem(write(late, tmp_path / "structure"))
    assert spec.model.input_delay.free and spec.model.input_delay.tau_min == 0.0
    assert load_problem(write(late, tmp_path / "diagnosis", mode="diagnosis")).model.input_delay is None


def test_the_confusion_table_counts_right_and_wrong_additions():
    frame = pd.DataFrame({
        "effect": ["coulomb", "coulomb", "none", "none"], "status": "ok",
        "first effect": ["coulomb", "offset", "offset", "offset"],
        "added": ["coulomb", "", "offset", ""], "added by simulation": ["", "coulomb,offset", "", ""],
        "first added": ["coulomb", "offset", "offset", None],
        "equation error fall": [8.0, np.nan, np.nan, np.nan], "free-run error fall": [4.0, 2.0, np.nan, np.nan],
        "start to final fall": [12.0, np.nan, np.nan, np.nan],
        "gap said": [False, True, False, False], "train gap": [1.0, 1.3, 0.99, 1.01],
    })
    table = confusion(frame)
    assert table.loc["coulomb", "gap said %"] == 50 and table.loc["none", "gap said %"] == 0
    assert table.loc["coulomb", "train gap (median x)"] == pytest.approx(1.15)
    assert table.loc["coulomb", "added first %"] == 50 and table.loc["none", "added first %"] == 0
    assert table.loc["coulomb", "equation error fall (median x)"] == 8.0
    assert table.loc["coulomb", "free-run error fall (median x)"] == 3.0
    assert table.loc["coulomb", "free-run error fall (least x)"] == 2.0
    assert table.loc["coulomb", "start to final fall (median x)"] == table.loc["coulomb", "start to final fall (least x)"] == 12
    assert table.loc["coulomb", "ranked first %"] == 50 and table.loc["coulomb", "added %"] == 100
    assert table.loc["coulomb", "added by simulation %"] == 50 and table.loc["coulomb", "wrong addition %"] == 50
    assert table.loc["none", "wrong addition %"] == 50 and table.loc["none", "most often first"] == "offset"
    noisy = confusion(frame.assign(noise=[0.01, 0.001, 0.01, 0.01]), ("effect", "noise"))
    assert noisy.index.names == ["hidden effect", "noise"]
    assert noisy.loc[("coulomb", 0.01), "added first %"] == 100 and noisy.loc[("coulomb", 0.001), "added first %"] == 0
    assert noisy.loc[("none", 0.01), "systems"] == 2
    nothing = confusion(frame.assign(status="failed", noise=0.01), ("effect", "noise"))
    assert nothing.empty and nothing.index.names == ["hidden effect", "noise"]  # printed, not raised


def test_the_error_falls_are_read_from_the_step_that_added_the_hidden_effect():
    equation = {"added": "offset", "test_mse_before": 4.0, "test_mse_after": 1.0, "fit_before": 90.0,
                "fit_after": 98.0}
    simulation = {"added": "coulomb", "kept": True, "test_rms_before": 0.3, "test_rms_after": 0.1}
    result = {"refinement": [equation], "simulation_diagnosis": {"steps": [simulation]}}
    assert _falls(result, "offset") == {"first added": "offset", "equation error fall": 4.0,
                                        "free-run error fall": pytest.approx(5.0)}
    late = _falls(result, "coulomb")
    assert late["first added"] == "offset" and np.isnan(late["equation error fall"])
    assert late["free-run error fall"] == pytest.approx(3.0)
    diverged = _falls({"refinement": [{**equation, "fit_before": None}]}, "offset")
    assert diverged["free-run error fall"] == np.inf and diverged["equation error fall"] == 4.0
    missed = _falls({"refinement": [], "simulation_diagnosis": {"steps": [{**simulation, "kept": False}]}}, "coulomb")
    assert missed["first added"] is None and np.isnan(missed["free-run error fall"])


def test_collinear_rivals_are_decided_by_the_free_run(tmp_path):
    # tuning seed 8: the equation error ranks cubic damping (x'^3) above the hidden
    # quadratic damping (x'|x'|), nearly collinear; before the free run decided between
    # them, both were added (measured: first added cubic_damping, free-run error fall 45x)
    row = run_one(8, "quadratic_damping", 0.001, 8.0, mode="diagnosis", known_gain=True, keep=tmp_path)
    assert row["status"] == "ok", row["error"]
    assert row["first effect"] == row["added"] == row["first added"] == "quadratic_damping"
    assert row["free-run error fall"] > 100  # measured 233x
    assert row["start to final fall"] > 100  # the starting model against the polished final one, both estimated
    (folder,) = tmp_path.iterdir()
    ranking = json.loads((folder / "result.json").read_text())["diagnosis"]["ranking"]
    fits = {r["effect"]: r["free_run_fit"] for r in ranking if r.get("free_run_fit") is not None}
    assert {"quadratic_damping", "cubic_damping"} <= set(fits)  # the group the equation error cannot split
    assert fits["quadratic_damping"] > max(f for e, f in fits.items() if e != "quadratic_damping") + 1  # % points
    assert max(r["validation_ratio"] for r in ranking) == next(r for r in ranking
                                                               if r["effect"] == "cubic_damping")["validation_ratio"]


def test_the_summary_counts_errors_within_the_delay_limit():
    frame = pd.DataFrame({"seed": [0, 1, 2, 3], "effect": "none", "noise": 0.01, "status": "ok",
                          "tau error %": [0.5, -3.0, 1.0, 8.0], "covers": True, "worst other %": 1.0, "seconds": 1.0,
                          "tau limit %": [1.0, 1.0, 2.0, 4.0], "tau error / limit": [0.5, -3.0, 0.5, 2.0]})
    table = summary(frame.reindex(columns=[*frame.columns, "tau_u error %", "tau_u covers"]))
    assert table.loc[("none", 0.01), "tau limit % median"] == 1.5
    assert table.loc[("none", 0.01), "within 1.96 limits %"] == 50
    assert table.loc[("none", 0.01), "with a limit"] == 4


MONTE_CARLO = 12
"""Noise realisations of one tuning-range system (seed 1: 8 s, noise 0.01 on x and f, gain known)."""


@pytest.mark.slow
def test_the_delay_limit_predicts_the_spread_of_the_estimates(tmp_path):
    """The standard error that delay_standard_error gives at the true delay is the spread of
    the output-error delay over noise realisations (within the sampling error of 12: a
    ratio in [0.6, 1.5]; measured 0.95)."""
    oscillator = draw(1, "none", 0.01, 8.0)
    model = run(write(oscillator, tmp_path, "structure", known_gain=True)).polish.system
    t, x, _, f = oscillator.simulate("train")
    taus, limits = [], []
    for k in range(MONTE_CARLO):
        rng = np.random.default_rng([1, k])
        record = Experiment(t, {"x": x + 0.01 * rng.standard_normal(t.size)},
                            {"f": f + 0.01 * rng.standard_normal(t.size)}, name="train")
        taus.append(output_error(model, [record], step=record.dt, max_iterations=50).parameters["tau"])
        limits.append(delay_standard_error(model, [record], oscillator.tau))
    spread = np.std(taus, ddof=1)
    assert 0.6 < spread / np.mean(limits) < 1.5, (spread, np.mean(limits))
    assert abs(np.mean(taus) - oscillator.tau) < spread, (np.mean(taus), oscillator.tau)



@pytest.mark.slow
def test_the_standard_error_counts_the_noise_on_the_force(tmp_path):
    """Tuning seed 25 (8 s) with noise 0.001 on x and 0.02 on the force: the force's noise
    moves the delay most, and the fitted residual shows little of it.  Over 12 noise
    realisations the spread of the output-error delay is what the standard error with the
    inputs' noise says (ratio in [0.6, 1.5]; measured 0.96), and more than twice what the
    residual alone says (measured 3.6)."""
    oscillator = draw(25, "none", 0.01, 8.0)
    model = run(write(oscillator, tmp_path, "structure", known_gain=True)).polish.system
    t, x, _, f = oscillator.simulate("train")
    taus, with_input, residual_only = [], [], []
    for k in range(MONTE_CARLO):
        rng = np.random.default_rng([25, k])
        record = Experiment(t, {"x": x + 0.001 * rng.standard_normal(t.size)},
                            {"f": f + 0.02 * rng.standard_normal(t.size)}, name="train")
        fit = output_error(model, [record], step=record.dt, max_iterations=50, input_noise=True)
        again = output_error(fit.system, [record], fit.initial, step=record.dt, max_iterations=1)
        taus.append(fit.parameters["tau"])
        # the profile's unit (both from the solver's Jacobian: no friction here, so that is the one reported)
        alone = (fit.standard_errors["tau"] ** 2 / fit.input_noise_inflation) ** 0.5
        assert alone == pytest.approx(again.standard_errors["tau"], rel=0.05)
        with_input.append(fit.standard_errors["tau"])
        residual_only.append(again.standard_errors["tau"])
    spread = np.std(taus, ddof=1)
    assert 0.6 < spread / np.mean(with_input) < 1.5, (spread, np.mean(with_input))
    assert spread / np.mean(residual_only) > 2.0, (spread, np.mean(residual_only))


def test_broadband_excitation_is_not_taken_for_input_noise(tmp_path):
    """The input-noise spread counts white noise on a smooth input (here 0.01 on the
    multisine force), never a white-noise excitation, whose samples noise_level cannot tell
    from noise (it would inflate every error by the whole input)."""
    from cvxid.identify.output_error import _linearise, _problem_at, input_noise_covariance
    oscillator = draw(1, "none", 0.01, 5.0)
    polished = run(write(oscillator, tmp_path, "structure", known_gain=True)).polish
    record = oscillator.experiment("train")
    problem = _problem_at(polished.system, [record], polished.initial, None)
    residual, jacobian = _linearise(problem)
    spread = input_noise_covariance(problem, problem.start, residual, jacobian)
    assert spread is not None and spread[problem.names.index("tau"), problem.names.index("tau")] > 0
    white = Experiment(record.time, {"x": record.output("x")},
                       {"f": np.random.default_rng(3).standard_normal(record.time.size)}, name="white")
    problem = _problem_at(polished.system, [white], polished.initial, None)
    residual, jacobian = _linearise(problem)
    assert input_noise_covariance(problem, problem.start, residual, jacobian) is None


@pytest.mark.parametrize("effect, seed, gain, smooth", [("none", 1, True, True), ("coulomb", 0, True, True),
                                                         ("stribeck", 0, True, True), ("none", 1, False, False)])
def test_standard_errors_that_depend_on_the_derivative_step_are_said(tmp_path, effect, seed, gain, smooth):
    """The final fit's standard errors come from finite differences.  A smooth simulation
    gives the same ones at a tenfold step (measured: within a factor 1.03 on 60 tuning
    systems without friction).  A friction whose stops are located is one too: Coulomb
    (tuning seeds 0-9: within 1.016; 4.0-fold on seed 0 when the friction was a clip at
    every stage) and Stribeck (seeds 0-3: within 1.006; 4-17 when its sign switched inside
    a step).  A nearly singular fit moves them (seed 1 with the gain free, trading with the
    stiffness: 1.29): the printout says so and names the parameter; the larger errors are
    reported."""
    oscillator = draw(seed, effect, 0.01, 8.0)
    result = run(write(oscillator, tmp_path, "structure", known_gain=gain))
    spread = result.polish.jacobian_spread
    said = (f"standard errors depend on the finite-difference step (up to {spread:.2g}x for "
            f"{result.polish.jacobian_spread_at})") in str(result)
    if smooth:
        assert spread < 1.05 and not said
    else:
        assert spread > 1.25 and said


@pytest.mark.parametrize("inflation", [1.0, 4.0])
def test_the_delay_profile_threshold_counts_the_input_noise(inflation):
    """The profile interval keeps the delays whose squared simulation error lies within
    kappa * chi2(0.95) / n_eff of the best, kappa the variance the inputs' noise adds to the
    delay's (as the standard error counts it): a parabola's interval is sqrt(kappa) wider."""
    from types import SimpleNamespace

    from scipy.stats import chi2

    from cvxid.identify.output_error import _interval

    n_eff, curvature, tau = 1000.0, 50.0, 0.15
    taus = np.linspace(0.05, 0.25, 2001)
    points = {float(t): (float(np.sqrt(1.0 + curvature * (t - tau) ** 2)),
                         SimpleNamespace(parameters={"tau": float(t), "k": 6.0 + 10.0 * (t - tau)},
                                         standard_errors={"tau": 0.0, "k": 0.01})) for t in taus}
    best = SimpleNamespace(parameters={"tau": tau, "k": 6.0}, effective_rows=n_eff, rms_after=1.0,
                           input_noise_inflation=inflation)
    profile = _interval(points, best)
    low, high = profile.interval
    half = np.sqrt(inflation * chi2.ppf(0.95, 1) / n_eff / curvature)
    assert low == pytest.approx(tau - half, rel=1e-4) and high == pytest.approx(tau + half, rel=1e-4)
    # a parameter that trades with the delay: its refitted values over the kept delays, each with its own
    # interval at that delay (the union of the conditional intervals)
    assert profile.ranges["k"] == pytest.approx((6.0 - 10 * half - 1.96 * 0.01, 6.0 + 10 * half + 1.96 * 0.01),
                                                abs=1e-3)


def test_a_parameter_that_trades_with_the_delay_reaches_the_delay_intervals_ends():
    """A tenth outside check: x'' + 0.8 x' - 2 x = f - 6 x(t - 0.08), the gain given; the
    damping trades with the delay (c + b tau is what the record holds), and its interval,
    the hull of the fits inside the delay's, stopped at the last inside fit (c 0.814 … 1.044
    for 0.8, the delay's interval reaching 0.077).  On a coarse profile whose crossings lie
    between its points, c is interpolated at each crossing as the delay is."""
    from types import SimpleNamespace

    from cvxid.identify.output_error import _interval

    tau, taus = 0.1, np.linspace(0.0, 0.2, 11)  # (points 0.02 apart; the interval's ends between them)

    def fit(t):
        return SimpleNamespace(parameters={"tau": float(t), "c": 0.32 + 6.0 * t}, standard_errors={"c": 0.0})

    points = {float(t): (float(np.sqrt(1.0 + 5.0 * (t - tau) ** 2)), fit(t)) for t in taus}
    best = SimpleNamespace(parameters={"tau": tau, "c": 0.92}, effective_rows=1000.0, rms_after=1.0,
                           input_noise_inflation=1.0)
    profile = _interval(points, best)
    low, high = profile.interval
    assert 0.06 < low < 0.08 and 0.12 < high < 0.14  # (the inside fits end at 0.08 and 0.12)
    assert profile.ranges["c"] == pytest.approx((0.32 + 6.0 * low, 0.32 + 6.0 * high), rel=1e-12)


def test_a_profile_fit_that_diverged_bounds_the_delay_interval_where_it_is_and_is_said(recwarn):
    """A ninth outside check's disk, its gain free: the output-error fits diverged at every
    delay but 0, and the interval, crossing towards an infinite error, read 0 … 0.  A
    diverged neighbour says nothing of where the bound is crossed: the interval reaches it,
    and the run says why."""
    from types import SimpleNamespace

    from cvxid.app.run import _warn_diverged_profile
    from cvxid.errors import CvxidWarning
    from cvxid.identify.output_error import _interval

    taus = [0.0, 0.003125, 0.00625, 0.5]
    fit = SimpleNamespace(parameters={"tau": 0.0, "k": 6.0}, standard_errors={"tau": np.inf, "k": 0.01})
    points = {0.0: (0.0177, fit), **{t: (np.inf, None) for t in taus[1:]}}
    best = SimpleNamespace(parameters={"tau": 0.0, "k": 6.0}, effective_rows=3800.0, rms_after=0.0177,
                           input_noise_inflation=1.0)
    profile = _interval(points, best)
    assert profile.interval == (0.0, 0.003125)  # (0.0, 0.0) before
    # the interval it quotes is the printed one, the profile's hulled with the standard error's (a twelfth outside
    # check read 0.075 … 0.07625 s in this warning, 0.065 … 0.087 s printed)
    _warn_diverged_profile(SimpleNamespace(profile=profile, interval=lambda name: (0.0, 0.0042)))
    said = str(recwarn.pop(CvxidWarning).message)
    assert "diverged at 3 of the 4 delays" in said and "0.003125" in said and "gain" in said
    assert "interval (0 … 0.0042 s)" in said
    finite = _interval({t: (1.0 + (t - 0.1) ** 2, SimpleNamespace(parameters={"tau": t, "k": 6.0},
                                                                  standard_errors={"tau": 0.0, "k": 0.01}))
                        for t in np.linspace(0.0, 0.2, 41)}, SimpleNamespace(
        parameters={"tau": 0.1, "k": 6.0}, effective_rows=3800.0, input_noise_inflation=1.0))
    _warn_diverged_profile(SimpleNamespace(profile=finite))  # nothing diverged: nothing said
    assert not [w for w in recwarn if issubclass(w.category, CvxidWarning)]
    # a flat valley whose edge, not the estimate's neighbour, is a diverged fit (a stranger's review)
    valley = {t: (1.0, SimpleNamespace(parameters={"tau": t, "k": 6.0}, standard_errors={"tau": 0.0, "k": 0.01}))
              for t in np.linspace(0.0, 0.04, 5)}
    valley.update({t: (np.inf, None) for t in (0.05, 0.06)})
    edge = _interval(valley, SimpleNamespace(parameters={"tau": 0.02, "k": 6.0}, effective_rows=3800.0,
                                             input_noise_inflation=1.0))
    assert edge.interval == (0.0, 0.05)
    _warn_diverged_profile(SimpleNamespace(profile=edge, interval=lambda name: edge.interval))
    assert "at the edge of the delay's interval (0.05 s)" in str(recwarn.pop(CvxidWarning).message)


def test_intervals_walk_the_valley_of_a_free_gain(tmp_path):
    """Tuning seed 2, the gain estimated: the record does not separate the gain from the
    stiffness (the delay's profile spans most of its range), the local standard errors see
    one point of that valley and none of the four Wald intervals covered its truth; each
    interval now hulls the parameter's refitted values along the delay's profile and all
    four cover, and the run says which combination is determined."""
    oscillator = draw(2, "none", 0.01, 8.0)
    out = run(write(oscillator, tmp_path, "structure", known_gain=False))
    polish = out.polish
    truth = {k: v for k, v in oscillator.truth.items() if k in polish.parameters and k != "tau"}
    assert set(truth) == {"m", "x", "x'", "gain"}
    wald = [abs(polish.parameters[k] - v) <= 1.96 * polish.standard_errors[k] for k, v in truth.items()]
    assert not any(wald), wald  # (what the intervals were)
    for name, value in truth.items():
        low, high = polish.interval(name)
        assert low <= value <= high, (name, value, low, high)
    said = [w for w in out.warnings if "not identified separately" in w or "not determined apart" in w]
    assert len(said) == 1 and "x - gain" in said[0], out.warnings
    assert not any("does not determine x" in w for w in out.warnings), out.warnings  # (not "remove x")


@pytest.mark.slow
def test_the_polish_ends_at_the_best_point_its_profile_found(tmp_path):
    """Held-out tuning seed 17 (Coulomb friction, 46 s, noise 0.01, the gain given): the
    profile's refined edges found a delay that fits 16 noise units of squared error better
    than the estimate, which stayed at 0.1938 (-4.5 %) for a truth of 0.2028; the polish
    now fits again from there (measured: +0.92 %, its interval covering)."""
    oscillator = draw(17, "coulomb", 0.01)
    result = run(write(oscillator, tmp_path, known_gain=True))
    assert abs(result.system.tau / oscillator.tau - 1) < 0.02
    low, high = result.polish.interval("tau")
    assert low <= oscillator.tau <= high


@pytest.mark.slow
def test_an_input_delay_is_not_judged_by_unprofiled_polishes(monkeypatch):
    """A stick-slip record (report seed 1017 with a friction of 100-150 % of the spring's
    force, `examples/stick_slip_diagnosis.py`): the friction is added; the input delay
    after it, judged by two models polished without a delay profile, was added too (tau_u
    0.31 s standing in for a fed-back delay the equation error had put at 0; the final
    polish sets it to 1.6e-4).  A delay is judged by the refit's simulation alone."""
    monkeypatch.setattr(heldout_module, "EFFECT_SHARE", (1.0, 1.5))
    row = heldout_module.run_one(1017, "coulomb", 0.01, 8.0, mode="diagnosis", known_gain=True)
    assert row["status"] == "ok" and row["added"] == "coulomb", row
    assert abs(row["tau error %"]) < 3 and row["covers"]  # (measured -1.7 %; +2.8 % with the input delay)


def test_an_effect_outside_the_catalogue_is_said_from_the_record_it_was_fitted_on(tmp_path):
    """Held-out tuning seed 2 with a hidden friction tanh(x'/v) (outside the diagnosis's
    catalogue), noise 0.01, 8 s, from the base terms with the diagnosis: the final model of
    the catalogue's terms missed the test record by 1.58 times what its noise allows, under
    the test record's threshold of 2, and nothing was said; its free run of the training
    record, from the polish's own start, misses by 1.31 times, where complete models of the
    tuning seeds stay within 1.032.  The same seed without the effect says nothing."""
    from cvxid.app.run import TRAINING_INCOMPLETE

    for effect, said in (("smooth_friction", True), ("none", False)):
        oscillator = draw(2, effect, 0.01, 8.0)
        assert any(t.startswith("tanh(x'") for t in oscillator.terms) == said
        result = run(write(oscillator, tmp_path / effect, "diagnosis")).to_dict()
        gap = (100 - result["train_fit_percent"]) / (100 - result["train_fit_percent_noise_ceiling"])
        test_gap = (100 - result["test_fit_percent"]) / (100 - result["test_fit_percent_noise_ceiling"])
        gaps = [w for w in result["warnings"] if "part of the dynamics may be missing" in w]
        assert (gap >= 1.2 if said else gap < TRAINING_INCOMPLETE) and test_gap < 2, (gap, test_gap)
        assert bool(gaps) == said, gaps
        if said:
            assert gaps[0].startswith("the final model's free run misses the training record it was fitted on by")
