"""Values the spec gives (a mass, a feedback gain, a tie) checked against the record
(cvxid.identify.given): a thirteenth outside check gave a mass 10 % high and a tie that
the data contradict, and the run moved the delay and the damping in silence."""

import json
import tomllib

import numpy as np
import pytest

from cvxid.app.cli import main
from cvxid.app.report import plain
from cvxid.app.run import run
from cvxid.identify.output_error import residual
from cvxid.spec.load import parse_problem

from .conftest import ROOT

TRUTH = {"m": 1.0, "x'": 0.5, "x": 6.0, "x^3": 2.0, "gain": 1.5, "tau": 0.15}
SPEC = """name = "given"
[truth]
mass = 1.0
coefficients = { "x'" = 0.5, "x" = 6.0, "x^3" = 2.0 }
delay = { signal = "x", gain = 1.5, tau = 0.15 }
history = "zero"
""" + "".join(f"""
[data.{which}.simulate]
duration = {duration}
dt = 2e-3
x0 = {x0}
seed = {seed}
noise = {{ output = 0.01, input = 0.01 }}
input = [{{ kind = "sine", amplitude = 3.0, omega = {w1} }}, {{ kind = "sine", amplitude = 2.0, omega = {w2}, phase = 1.0 }}]
""" for which, duration, x0, seed, w1, w2 in (("train", 16.0, 0.3, 1, 1.9, 4.7), ("test", 8.0, -0.2, 2, 2.9, 6.1))) + """
[model]
@MODEL@
[model.library]
terms = ["x", "x'", "x^3"]
[model.delay]
signal = "x"
method = "exact"
tau_max = 0.5
gain = 1.5
@TIE@
[fit]
velocity = "savgol"
refine = "output_error"
"""


def text(model: str = "", tie: str = "") -> str:
    return SPEC.replace("@MODEL@", model).replace("@TIE@", tie)


def spec(model: str = "", tie: str = ""):
    return parse_problem(tomllib.loads(text(model, tie)), ROOT)


def test_a_mass_given_10_percent_high_is_said_with_its_estimate_and_where_the_delay_goes(tmp_path, monkeypatch):
    path = tmp_path / "spec.toml"
    path.write_text(text("inertia = false\nmass = 1.1"))
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(path), "--out", "out", "--quiet"]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    said = " ".join(result["warnings"])
    assert "the record disagrees with" in said and "the mass m = 1.1: estimated" in said
    assert "inertia = true in [model]" in said  # the fix, named
    checks = {c["name"]: c for c in result["polish"]["given"]}
    mass = checks["m"]
    assert mass["disagrees"] and mass["kind"] == "mass" and mass["given"] == pytest.approx(1.1)
    assert mass["estimate"] == pytest.approx(TRUTH["m"], rel=0.02)
    assert result["tau"]["estimate"] > 1.5 * TRUTH["tau"]  # the mass given: the delay far off (measured 0.30)
    assert mass["tau"] == pytest.approx(TRUTH["tau"], rel=0.25)  # freed, it comes back (measured 0.182)
    assert mass["rms"] < 0.8 * mass["rms_given"] and mass["p"] < 1e-3
    estimated = run(spec()).polish  # what a run with the mass estimated gives, the check quotes
    assert mass["estimate"] == pytest.approx(estimated.parameters["m"], rel=1e-4)
    assert mass["interval"] == pytest.approx(list(estimated.interval("m")), rel=1e-4)
    assert checks["gain"]["kind"] == "gain"  # every given value is checked and listed


def test_right_given_values_raise_no_alarm():
    out = run(spec("inertia = false\nmass = 1.0", '[[model.tie]]\nleft = "x^3"\nright = "x"\nfactor = 0.3333333333'))
    checks = out.given
    assert {c.kind for c in checks} == {"mass", "gain", "tie"}
    assert not any(c.disagrees for c in checks)
    assert not any("disagrees with" in w for w in out.warnings)
    assert all(0 <= c.p <= 1 and c.statistic >= 0 for c in checks)


def test_a_tie_the_record_contradicts_is_said_with_the_factor_it_wants():
    out = run(spec("", '[[model.tie]]\nleft = "x^3"\nright = "x"\nfactor = 0.2'))
    tie = next(c for c in out.given if c.kind == "tie")
    assert tie.disagrees and tie.what == "the tie x^3 = 0.2 x"
    assert tie.estimate == pytest.approx(TRUTH["x^3"] / TRUTH["x"], rel=0.05)  # (the factor 1/3)
    said = next(w for w in out.warnings if "disagrees with" in w)
    assert "the tie x^3 = 0.2 x: its factor estimated" in said and "untie them ([[model.tie]])" in said


def test_a_gain_20_percent_high_that_the_stiffness_absorbs_is_checked_and_not_said():
    """The record cannot reject it: the stiffness and the delay take it up within the noise
    (a thirteenth outside check's five systems; the run says it checked, not that it is right)."""
    out = run(spec())  # (the gain 1.5 given right: the reference fit)
    high = run(parse_problem(tomllib.loads(text().replace("tau_max = 0.5\ngain = 1.5", "tau_max = 0.5\ngain = 1.8")),
                             ROOT))  # (the model's gain; the truth's stays 1.5)
    gain = next(c for c in high.given if c.kind == "gain")
    assert not gain.disagrees and not gain.reason and gain.p > 0.01
    assert high.polish.rms_after < 1.02 * out.polish.rms_after  # (the same simulation error, within 2 %)
    assert "the feedback gain = 1.8 p = " in high.summary()
    assert high.polish.parameters["x"] != pytest.approx(out.polish.parameters["x"], rel=0.01)  # (the stiffness took it)


def test_a_delay_range_that_misses_the_delay_does_not_fault_right_given_values():
    """With ``tau_max`` 0.1 s for a delay of 0.15, freeing the right gain soaked up the
    misfit and it was said to disagree (a re-review); freed, the delay stays at the top:
    the range is the likelier cause, and the delay's warning says to raise it."""
    short = text("inertia = false\nmass = 1.0").replace("tau_max = 0.5", "tau_max = 0.1")
    short = run(parse_problem(tomllib.loads(short), ROOT))
    assert short.polish.parameters["tau"] == pytest.approx(0.1, abs=1e-3)
    assert not any(c.disagrees for c in short.given) and not any("disagrees with" in w for w in short.warnings)
    bound = next(w for w in short.warnings if "tau_max" in w)
    assert "raise [model.delay] tau_max" in bound and "check it first" not in bound


def test_a_taylor_delay_with_a_given_mass_is_polished_and_its_values_listed_unchecked():
    """The polish re-added a Taylor delay's share to a given mass's x'' column on every
    update and ended in a traceback from scipy (ValueError: array must not contain infs or
    NaNs); its given values cannot be freed apart from the delay's shares and are listed
    as not checked."""
    taylor = text("inertia = false\nmass = 1.1").replace('method = "exact"', 'method = "taylor"').replace(
        "tau_max = 0.5\n", "")
    out = run(parse_problem(tomllib.loads(taylor), ROOT))
    assert out.model.system().mass == pytest.approx(1.1) and np.isfinite(out.polish.rms_after)
    assert {c.kind for c in out.given} == {"mass", "gain"} and all("Taylor" in c.reason for c in out.given)
    assert "the mass m = 1.1 not checked (a Taylor delay's model, whose columns" in out.summary()


def test_a_coupled_system_with_one_given_and_one_free_gain_simulates_at_its_own_gains():
    """The polish zipped the free gains with every equation: with x's gain given and y's
    free, y's gain started at x's (a residual at the model's own values 400 times its
    fit's), and the score tests of the diagnosis and of the given values read a wrong model."""
    from .test_simulation_diagnosis import COUPLED

    text = COUPLED.replace("delay_gain = 0.5\nlibrary", "library").replace(  # y's gain estimated, x's given
        'terms = ["x\'", "x", "y"]', 'terms = ["x\'", "x", "y", "x^3"]')  # (the truth's terms)
    assert text.count("delay_gain") == COUPLED.count("delay_gain") - 1 and "x^3\"]" in text
    out = run(parse_problem(tomllib.loads(text), ROOT))
    assert "y:gain" in out.polish.parameters and "x:gain" not in out.polish.parameters
    gain = out.to_dict()["polish"]["given"]
    assert [c["kind"] for c in gain] == ["gain"] and gain[0]["name"] == "x:gain" and not gain[0]["disagrees"]
    r = residual(out.polish.system, [out.train], out.polish.initial)
    assert np.sqrt(np.mean(r**2)) == pytest.approx(out.polish.rms_after, rel=1e-6)


def test_a_right_gain_that_soaks_up_a_missing_effect_on_the_training_record_is_not_said():
    """A held-out system (`cvxid bench --heldout`, report seed 1009) with a smooth friction
    outside the catalogue the diagnosis cannot add, noise 0.01, 8 s, the gain given right:
    freed, the gain went to 36 (truth 3.33) and the training simulation error fell beyond
    chance, so the check said the record disagreed with the right gain.  The freed model's
    free run misses the test record by more than the given one's: nothing is said (measured:
    training RMS 0.010007 against 0.010028, test 0.0191 against 0.0162)."""
    from cvxid.tools.heldout import draw, identify_drawn

    oscillator = draw(1009, "smooth_friction", 0.01, 8.0)
    out = identify_drawn(oscillator, mode="diagnosis", known_gain=True)
    gain = next(c for c in out.given if c.kind == "gain")
    assert gain.rms is not None and gain.rms < gain.rms_given  # refitted, better on the training record
    assert abs(gain.estimate / gain.given) > 5  # (freed, it soaks up the friction)
    assert gain.test_rms > 1.1 * gain.test_rms_given and gain.contradicted and not gain.disagrees
    assert not [w for w in out.warnings if "disagrees with" in w], out.warnings
    written = json.loads(json.dumps(plain(out.to_dict())))["polish"]["given"][0]  # as result.json has it
    assert written["test_contradicts"] is True and written["test_rms"] == pytest.approx(gain.test_rms)
