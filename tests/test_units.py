"""The same system in other units gives the same answer (an outside check found absolute
constants that only suited a plant of about a second, sampled at 1 kHz, in metres).

Rescaling a record changes its numbers, not its information: positions and forces written
``a`` times larger (micrometres for metres) leave every linear coefficient, and a time axis
``s`` times shorter (a plant ``1/s`` times faster) gives

.. math:: m s^2 y'' + c s\\,y' + k y + k_3 y^3 = f + b\\,y(u - s\\tau),

so an estimator free of absolute constants returns the same relative errors."""

import numpy as np
import pytest

from cvxid.data.experiment import Experiment
from cvxid.diagnosis.candidates import feedback_bound
from cvxid.diagnosis.compare import k_step_samples
from cvxid.diagnosis.simulation import score_candidates
from cvxid.identified import IdentifiedModel
from cvxid.identify.output_error import polish
from cvxid.metrics import band_edge
from cvxid.model.delay import DelayedFeedback
from cvxid.model.equation import ModelSpec
from cvxid.model.library import Library
from cvxid.model.terms import parse_term
from cvxid.simulate import System, simulate

TRUE = {"m": 1.0, "x'": 0.5, "x": 4.0, "x^3": 1.0, "tau": 0.15, "gain": 1.5}


def record(terms=("x'", "x", "x^3"), amplitude=1.0, time_scale=1.0, dt=1e-3, duration=6.0, seed=3):
    """A delayed oscillator's noisy record (noise 1 % of its spread), its positions and
    forces times ``amplitude``, its time axis times ``time_scale``."""
    t = np.arange(int(round(duration / dt)) + 1) * dt
    force = lambda s: 3 * np.sin(2.1 * s) + 2 * np.sin(5.3 * s + 1) + 1.5 * np.sin(9.7 * s)  # noqa: E731
    system = System(tuple(parse_term(n) for n in terms), np.array([TRUE[n] for n in terms]), 1.0, "x",
                    TRUE["gain"], TRUE["tau"], 0, "zero")
    x, _ = simulate(system, t, force, 0.5, 0.0)
    x = x + 0.01 * x.std() * np.random.default_rng(seed).standard_normal(t.size)
    return Experiment(time_scale * t, {"x": amplitude * x}, {"f": amplitude * force(t)}, "e")


def start(terms, amplitude=1.0, time_scale=1.0, tau=0.12):
    """A model 10 % off the truth (the delay 0.12 for 0.15), in the record's units."""
    delay = DelayedFeedback("x", 0, TRUE["gain"], method="exact", tau_max=0.4 * time_scale)
    spec = ModelSpec(Library(parse_term(n) for n in terms), delay=delay, nonnegative=("x''",))
    units = {"x''": time_scale**2, "x'": time_scale, "x": 1.0, "x^3": amplitude**-2}
    values = {"x''": 1.1, "x'": 0.45, "x": 4.4, "x^3": 0.9}
    return IdentifiedModel(spec, {n: values[n] * units[n] for n in ("x''", *terms)}, tau=tau * time_scale)


def relative(fit, amplitude=1.0, time_scale=1.0) -> dict[str, float]:
    """The polished parameters back in the reference's units."""
    units = {"m": time_scale**2, "x'": time_scale, "x": 1.0, "x^3": amplitude**-2, "tau": time_scale}
    return {n: v / units[n] for n, v in fit.parameters.items() if n in units}


def test_a_band_edge_is_the_same_at_every_sample_rate():
    """The spectra resolve the same band in the record's own time (a fixed 4,096-sample
    Welch segment resolved 0.24 Hz at 1 kHz and 4.9 Hz at 20 kHz)."""
    edges = [band_edge(record(dt=dt).output("x"), dt) for dt in (1e-3, 5e-5)]
    assert edges[1] == pytest.approx(edges[0], rel=0.02)
    assert 2 < edges[0] < 10  # between the resonance, near 2 rad/s, and the forcing's top line


def test_a_polish_in_micrometres_is_the_polish_in_metres():
    """The output-error fit stops by its own tests, not by the size of the numbers (in
    micrometres its gradient, in the squares of the data's units, passed the solver's
    absolute test at the start: the delay stayed at 0.12 for 0.15, 15 % from the fit in
    metres)."""
    terms = ("x'", "x", "x^3")
    fits = [relative(polish(start(terms, a), record(amplitude=a), grid=0, final=False), a) for a in (1.0, 1e-6)]
    assert fits[0]["tau"] == pytest.approx(TRUE["tau"], rel=0.1)  # (from 0.12: measured 0.1407)
    for name, value in fits[0].items():
        assert fits[1][name] == pytest.approx(value, rel=1e-3), name


def test_a_record_a_billion_times_larger_is_identified_alike():
    """Positions and forces 1e9 times larger (micrometres of a 1 km stroke, an encoder's
    counts): absolute walls called every simulation diverged (beyond 1e8: "the model is
    unstable"), read good profile fits as diverged (a residual over 1e6: the delay's
    interval widened), and the estimated start of a comparison stopped at its guess (scipy's
    gradient test is not unit-free: 95.9 % for 99.0 %).  Now each is relative to the data."""
    import cvxid

    terms = ("x'", "x", "x^3")
    fits, intervals, compared = [], [], []
    for a in (1.0, 1e9):
        fit = polish(start(terms, a), record(amplitude=a), final=False)
        fits.append(relative(fit, a))
        intervals.append(fit.profile.interval)
        compared.append(cvxid.compare(fit.system.single, record(amplitude=a, seed=4)).fit_percent)
    for name, value in fits[0].items():
        assert fits[1][name] == pytest.approx(value, rel=1e-3), name
    assert intervals[1] == pytest.approx(intervals[0], rel=1e-3)
    assert compared[1] == pytest.approx(compared[0], abs=0.01) and compared[0] > 98


def test_a_plant_a_hundred_times_faster_gets_the_same_delay():
    """The profile's coarse step (about 1e-3 s) compared every 100th sample of a record at
    100 kHz, 60 of them: the delay 0.117 for the reference's 0.141 (truth 0.15).  Now the
    coarse fits compare at least :data:`~cvxid.identify.output_error.MIN_COMPARED` samples
    (here every third), and both intervals cover the truth."""
    terms = ("x'", "x", "x^3")
    fits = {s: polish(start(terms, time_scale=s), record(time_scale=s)) for s in (1.0, 0.01)}
    taus = {s: relative(f, time_scale=s)["tau"] for s, f in fits.items()}
    assert taus[0.01] == pytest.approx(taus[1.0], rel=0.01)
    for s, f in fits.items():
        low, high = np.array(f.profile.interval) / s
        assert low <= TRUE["tau"] <= high, (s, low, high)


def test_a_score_test_in_micrometres_is_the_score_test_in_metres():
    """A hidden cubic stiffness scores the same whatever the position's unit (its
    coefficient's finite-difference step was 1e-8 in the data's units: 9.1 in metres, 0 in
    micrometres)."""
    scores = []
    for a in (1.0, 1e-6):
        train = record(amplitude=a)
        fitted = polish(start(("x'", "x"), a), train, grid=0, final=False).model
        scores.append(float(score_candidates(fitted, train, ["cubic_stiffness"])["score"].iloc[0]))
    assert scores[0] > 1  # (measured 2.65)
    assert scores[1] == pytest.approx(scores[0], rel=1e-3)


def test_the_k_step_horizon_and_the_fed_back_delays_range_follow_the_plants_time():
    """The k-step check looks the same share of a period ahead (a tenth of a second was 2
    samples of a plant 100 times faster), and the ``delay`` candidate searches delays of a
    plant 100 times slower (it searched 0 … 0.5 s, a twenty-fourth of a 12 s delay)."""
    samples = {s: k_step_samples(record(time_scale=s, dt=1e-3), ["x"]) for s in (0.01, 1.0, 100.0)}
    assert samples[0.01] == samples[1.0] == samples[100.0] >= 20
    slow = record(time_scale=100.0, duration=40.0)
    assert feedback_bound("x", slow) >= 100 * TRUE["tau"]
