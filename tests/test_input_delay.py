"""An input that acts late, u(t - tau_u): estimated, diagnosed, simulated, saved, exported.

Records are simulated here (a cubic oscillator driven by a seeded multisine that reaches
it 0.05 s late, 10 ms sampling, noise 0.01 on output and input) and written as CSV files
with a spec, as a user would have them.
"""

import json
from dataclasses import replace

import numpy as np
import pytest

from cvxid import CvxidError
from cvxid.app.run import run
from cvxid.spec.load import parse_problem
from cvxid.identified import IdentifiedModel
from cvxid.model.terms import parse_term
from cvxid.simulate import System, simulate

from .conftest import ROOT

TERMS = ("x'", "x", "x^3")
TRUTH = {"m": 1.0, "x'": 0.4, "x": 4.0, "x^3": 0.5}
TAU_U = 0.05


def write(folder, tau_u=TAU_U, seed=0, noise=0.01, model="", diagnose=False, dt=0.01, duration=60.0, test=15.0):
    """Train and test CSV files and a spec reading them; ``model``: extra [model] lines."""
    rng = np.random.default_rng(seed)
    freqs = np.linspace(0.3, 3.0, 8) * 2 * np.pi
    phases = rng.uniform(0, 2 * np.pi, freqs.size)

    def u(s):
        return 1.5 * np.sin(np.multiply.outer(s, freqs) + phases).sum(axis=-1) / np.sqrt(freqs.size)

    system = System(tuple(parse_term(n) for n in TERMS), np.array([TRUTH[n] for n in TERMS]), 1.0, "x")
    t = np.arange(int(round((duration + test) / dt)) + 1) * dt
    x, _ = simulate(system, t, lambda s: u(s - tau_u), 0.3, -0.2)
    y, f = x + noise * rng.standard_normal(t.size), u(t) + noise * rng.standard_normal(t.size)
    cut = int(round(duration / dt))
    for name, part in (("train", slice(0, cut)), ("test", slice(cut, None))):
        np.savetxt(folder / f"{name}.csv", np.column_stack([t[part], y[part], f[part]]), delimiter=",",
                   header="t,x,f", comments="", fmt="%.10g")
    data = "".join(f'[data.{n}]\nfile = "{n}.csv"\noutput = "x"\ninput = "f"\n' for n in ("train", "test"))
    spec = (f'name = "input_delay"\n{data}[model]\n{model}\n[model.library]\nterms = ["x\'", "x", "x^3"]\n'
            '[fit]\nestimator = "lstsq"\nrefine = "output_error"\n' + ("[diagnose]\nrefine = true\n" if diagnose else ""))
    (folder / "spec.toml").write_text(spec)
    return folder / "spec.toml"


@pytest.mark.parametrize("seed", [0, 1])
def test_an_input_delay_is_estimated_with_an_interval_that_covers_it(tmp_path, seed):
    result = run(write(tmp_path, seed=seed, model="input_delay = {}"))
    estimate, (low, high) = result.input_delay["estimate"], result.input_delay["interval"]
    assert estimate == pytest.approx(TAU_U, rel=0.04)  # measured: within 2 % on seeds 0-2 and 10-15
    assert low < TAU_U < high and high - low < 0.2 * TAU_U
    physical = result.model.physical
    for name in ("m", "x'", "x"):
        assert physical[name] == pytest.approx(TRUTH[name], rel=0.02)
    assert result.model.equation().endswith(f"= f(t - {estimate:.6g})")
    assert result.to_dict()["input_delay"]["method"] == "output_error"


def test_without_an_input_delay_the_estimate_stays_within_a_sample_of_zero(tmp_path):
    result = run(write(tmp_path, tau_u=0.0, seed=12, model="input_delay = {}"))
    assert result.input_delay["estimate"] < 0.005  # half a sample
    assert result.input_delay["interval"][0] == 0.0


def test_a_missing_input_delay_is_ranked_first_and_added(tmp_path):
    without = run(write(tmp_path, seed=11, noise=0.002, diagnose=True))
    ranking = without.diagnosis.ranking
    assert ranking.index[0] == "input_delay" and ranking["err"].iloc[0] > 0.5
    assert [s.added for s in without.refinement.steps] == ["input_delay"]
    step = without.refinement.steps[0]
    assert step.fit_after > step.fit_before and step.test_mse_after < step.test_mse_before / 4
    assert without.model.spec.input_tau == pytest.approx(TAU_U, rel=0.03)


def test_the_model_file_keeps_the_input_delay_and_simulates_alike(tmp_path):
    result = run(write(tmp_path, seed=2, model="input_delay = 0.05"))
    assert result.model.physical["tau_u"] == 0.05 and result.input_delay is None  # known: not estimated
    result.model.save(tmp_path / "model.json")
    loaded = IdentifiedModel.load(tmp_path / "model.json")
    assert loaded.spec.input_delay == result.model.spec.input_delay
    np.testing.assert_allclose(loaded.simulate(result.test)[0], result.model.simulate(result.test)[0], rtol=1e-12)
    assert json.loads((tmp_path / "model.json").read_text())["equations"]["x"]["model"]["input_delay"]["value"] == 0.05


def test_the_linearisation_delays_the_input_by_its_pade_approximation(tmp_path):
    result = run(write(tmp_path, seed=3, model="input_delay = 0.05"))
    lagged = result.model.linearized_tf()
    plain = IdentifiedModel(replace(result.model.spec, input_delay=None), result.model.coefficients).linearized_tf()
    w = np.array([1.0, 5.0, 20.0])
    ratio = lagged(1j * w) / plain(1j * w)
    np.testing.assert_allclose(np.abs(ratio), 1.0, atol=1e-6)
    np.testing.assert_allclose(np.angle(ratio), -w * 0.05, atol=1e-6)
    system = result.model.to_control()
    assert system.nstates == 2 + 6  # x, x' and the input delay's Padé states


@pytest.mark.parametrize("line, message", [
    ("input_delay = -0.1", "input_delay = -0.1 is out of range"),
    ("input_delay = { tau_min = 0.1, tau_max = 0.05 }", "needs tau_min < tau_max"),
    ("input_delay = { max = 0.1 }", "unknown key"),
    ("input_delay = 9.0", "input_delay = 9 s is more than half the shortest record"),
    ("input_delay = { tau_min = 5.0 }", "tau_min = 5 s is at or above the default tau_max"),
    ('input_delay = "auto"', "must be a number"),
])
def test_a_bad_input_delay_is_named(tmp_path, line, message):
    with pytest.raises(CvxidError, match=message):
        run(write(tmp_path, model=line))


def test_a_simulated_truth_with_a_late_input_is_identified_from_the_spec_alone(tmp_path):
    sim = ('duration = {d}\ndt = 0.01\nx0 = 0.3\nseed = {s}\nnoise = {{ output = 0.01, input = 0.01 }}\n'
           'input = [{{ kind = "sine", amplitude = 3.0, omega = 1.3 }}, {{ kind = "sine", amplitude = 2.0, omega = 3.7 }},'
           ' {{ kind = "sine", amplitude = 1.0, omega = 7.9 }}]\n')
    spec = tmp_path / "late.toml"
    spec.write_text(
        'name = "late"\n[truth]\nmass = 1.0\ncoefficients = { "x\'" = 0.4, "x" = 4.0, "x^3" = 0.5 }\ninput_delay = 0.04\n'
        f'[data.train.simulate]\n{sim.format(d=40.0, s=1)}[data.test.simulate]\n{sim.format(d=10.0, s=2)}'
        '[model]\ninput_delay = {}\n[model.library]\nterms = ["x\'", "x", "x^3"]\n'
        '[fit]\nestimator = "lstsq"\nrefine = "output_error"\n')
    result = run(spec)
    assert result.spec.truth.physical["tau_u"] == 0.04
    table = result.table()
    assert abs(table.loc["tau_u", "error %"]) < 3 and abs(table.loc["x", "error %"]) < 2


def test_the_reported_input_delay_is_the_models_after_the_refinement(tmp_path):
    """The diagnosis refits with the input delay profiled again: the report follows it."""
    spec = write(tmp_path, seed=4, model="input_delay = {}")
    text = spec.read_text().replace('terms = ["x\'", "x", "x^3"]', 'terms = ["x\'", "x^3"]')
    spec.write_text(text + "[diagnose]\nrefine = true\nsimulation = false\ncandidates = [\"linear_stiffness\"]\n")
    result = run(spec)
    assert [s.added for s in result.refinement.steps] == ["linear_stiffness"]
    assert result.input_delay["estimate"] == result.model.spec.input_tau == result.model.physical["tau_u"]
    assert result.input_delay["estimate"] == pytest.approx(TAU_U, rel=0.05)
    assert result.simulation_refinement is None  # switched off


def test_a_known_input_delay_is_kept_by_the_diagnosis(tmp_path):
    spec = write(tmp_path, seed=5, model="input_delay = 0.05", diagnose=True)
    result = run(spec)
    assert result.model.spec.input_delay.value == 0.05 and not result.model.spec.input_delay.free
    assert "input_delay" not in result.diagnosis.ranking.index


def _coupled_late(**model):
    """Two coupled oscillators (tests/test_simulation_diagnosis.py, its cubic stiffness in
    the model) whose shared input arrives 0.04 s late."""
    import tomllib

    from .test_simulation_diagnosis import COUPLED

    raw = tomllib.loads(COUPLED)
    raw["truth"]["input_delay"] = 0.04
    raw["model"]["equation"][0]["library"]["terms"].append("x^3")
    raw["model"].update(model)
    return raw


def test_a_coupled_system_estimates_its_shared_input_delay():
    """[model] input_delay for N = 2 (it was refused): one delay of the shared input, every
    equation's, estimated by the profile and the polish (measured 0.04004, interval 0.03995
    ... 0.04014)."""
    result = run(parse_problem(_coupled_late(input_delay={"tau_max": 0.1}), ROOT))
    late = result.to_dict()["input_delay"]
    assert late["estimate"] == pytest.approx(0.04, rel=0.01) and late["interval"][0] < 0.04 < late["interval"][1]
    assert result.physical["tau_u"] == late["estimate"]
    assert {m.spec.input_tau for m in result.system.models.values()} == {late["estimate"]}


def test_the_diagnosis_finds_a_coupled_systems_late_input():
    """The input_delay candidate for N = 2 (a one-equation candidate before): scored by the
    rate of the input in both equations, added first, and the polish estimates it."""
    raw = _coupled_late()
    raw["diagnose"] = {"refine": True}
    result = run(parse_problem(raw, ROOT))
    assert [s.added for s in result.refinement.steps] == ["input_delay"]
    step = result.refinement.steps[0]  # the free-run error falls (measured 90.9 -> 99.4 % from the estimated start)
    assert 100 - step.fit_before > 5 * (100 - step.fit_after)
    assert result.physical["tau_u"] == pytest.approx(0.04, rel=0.01)


def test_the_bootstrap_gives_no_spread_for_an_input_delay_it_holds(tmp_path):
    """A review: the bootstrap holds an input delay at its profiled estimate, and printed
    its spread as 0 (a 95 % interval of one value).  It has no spread to give: null, and
    "–" in the printed table."""
    spec = write(tmp_path, seed=0, model="input_delay = {}")
    spec.write_text(spec.read_text().replace('refine = "output_error"', 'refine = "none"\n'
                                             'bootstrap = { samples = 4, seed = 0 }'))
    result = run(spec)
    spread = result.to_dict()["bootstrap"]["physical"]
    assert np.isnan(spread["tau_u"]["std"]) and spread["x'"]["std"] > 0  # (null in result.json)
    row = next(line for line in result.summary().splitlines() if line.startswith("tau_u"))
    assert row.split()[-1] == "–"
