"""Coupled specs end to end: `cvxid run problems/flexible_joint.toml`, and the checks of
the coupled spec format."""

import json

import numpy as np
import pytest

import cvxid
from cvxid.app.cli import main
from cvxid.app.run import run
from cvxid.errors import CvxidError
from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.spec.load import load_problem, parse_problem

from .conftest import ROOT

SPEC = ROOT / "problems" / "flexible_joint.toml"


@pytest.mark.slow
def test_flexible_joint_spec_recovers_delay_and_stiffness_and_names_coulomb(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a shipped problem runs by its name from any folder
    assert main(["run", "flexible_joint", "--out", "out"]) == 0
    tmp_path = tmp_path / "out"
    result = json.loads((tmp_path / "result.json").read_text())
    physical, truth = result["physical"], result["truth"]
    # the issue asked for 5 %; the joint output-error fit reaches the noise floor
    # (measured: tau -0.03 %, k_s -0.91 %, J_eq +1.8 %; -0.04 %, -0.33 %, +0.85 % before the integrator's friction
    # became continuous: the rig's friction is smooth, tanh(v / 0.05), the model's sticks, and k_s and J_eq carry
    # the mismatch)
    assert physical["tau"] == pytest.approx(truth["tau"], rel=1e-3)
    assert physical["k_s"] == pytest.approx(truth["k_s"], rel=1.5e-2)
    assert physical["J_eq"] == pytest.approx(truth["J_eq"], rel=2.5e-2)  # the rig's friction is smooth, the model's sticks
    # the starting library lacks the friction: the diagnosis ranks it first and adds it
    assert result["diagnosis"]["ranking"][0]["term"] == "sign(theta')"
    steps = result["refinement"]
    assert [s["added"] for s in steps] == ["coulomb(theta)"]
    assert steps[0]["inclusion"] >= 0.7  # the acceptance rule's share of halves (measured 1.0)
    assert result["refinement_stopped"]["effect"] != "coulomb(theta)"  # where it stopped, and why
    assert steps[0]["test_mse_after"] < 0.1 * steps[0]["test_mse_before"]
    assert steps[0]["simulation_error_after"] < 0.2 * steps[0]["simulation_error_before"]
    assert physical["theta:sign(theta')"] == pytest.approx(0.05, rel=0.05)
    # the tie holds exactly, the free-run test fit is high on both angles
    assert result["coefficients"]["alpha:theta'"] == pytest.approx(-result["coefficients"]["theta:theta'"], rel=1e-12)
    assert min(result["test_fit_percent"].values()) > 95
    start = result["test_initial_state"]  # the free run starts from the state estimated on the test record
    assert start["method"] == "estimated" and set(start["position"]) == set(start["velocity"]) == {"theta", "alpha"}
    assert all(result["test_fit_percent"][c] >= result["test_fit_percent_record_start"][c] - 1e-9 for c in start["position"])
    # the training record's free run, by coordinate too: at the noise (measured 1.00 and 0.99 times its error),
    # where the test record's misses the rig's smooth friction (3.3 times for theta)
    gaps = {c: (100 - result["train_fit_percent"][c]) / (100 - result["train_fit_percent_noise_ceiling"][c])
            for c in start["position"]}
    assert all(0.95 < g < 1.05 for g in gaps.values()), gaps
    low, high = result["tau"]["interval"]  # the noise's share only: the rig's smooth friction is not in it
    assert low < physical["tau"] < high and high - low < 1e-3
    # the polish's intervals and standard errors are keyed as `physical` is, in its signs (a ninth outside check:
    # they were keyed by column, k_s's and B_l's negated, so "theta:alpha" -1.297 read [1.296, 1.298])
    intervals = result["polish"]["intervals"]
    assert set(physical) <= set(intervals) and set(physical) <= set(result["polish"]["standard_errors"])
    assert all(intervals[name][0] <= value <= intervals[name][1] for name, value in physical.items())
    assert physical["k_s"] > 0 and intervals["k_s"][0] > 0  # named -alpha: the coefficient is negative
    single = json.loads(json.dumps(run(load_problem("hidden_friction")).to_dict()))
    assert set(single) - set(result) == set() and single["coupled"] is False  # a coupled file has a single run's keys
    assert {"test_fit", "delay_profile", "refinement"} <= set(result["figures"])
    assert {"responses", "residuals"} <= set(result["figures"])  # before and after, and where: for every N
    assert "theta(t - " in result["equations"]["alpha"]  # the alpha equation reads the delayed theta
    # the joint model saved to JSON and loaded back simulates the same: the same coefficients, each comparison's
    # initial state fitted by least squares to its tolerance (the fits 2e-9 % apart on 2026-11-26)
    loaded = IdentifiedSystem.load(tmp_path / result["model_file"])
    fits = loaded.compare(load_problem(SPEC).experiment("test"))["fit_percent"]
    for coordinate, fit in result["test_fit_percent"].items():
        assert fits[coordinate] == pytest.approx(fit, abs=1e-6)


def test_corrupted_joint_model_files_are_refused(tmp_path):
    path = tmp_path / "model.json"
    for text, message in [("{", "not a JSON model file"), ('{"schema": "cvxid.identified/1"}', "incomplete or corrupted"),
                          ('{"schema": "cvxid.joint/1", "tau": 0.2}', "incomplete or corrupted"),
                          ('{"schema": "cvxid.system/1", "tau": 0.2, "ties": [], "equations": {}}', "no equations"),
                          ('{"schema": "cvxid.joint/9"}', "not a cvxid model file")]:
        path.write_text(text)
        with pytest.raises(CvxidError, match=message):
            IdentifiedSystem.load(path)


def test_files_of_both_earlier_schemas_still_load(tmp_path):
    """A one-equation file of schema cvxid.identified/1 and a coupled one of cvxid.joint/1
    (as the previous release wrote them) load and simulate like the system they describe."""
    result = run(_without_friction())
    system = result.system
    joint = {"schema": "cvxid.joint/1", "tau": system.tau,
             "ties": [{"left": a, "right": b, "factor": f} for a, b, f in system.ties],
             "equations": {label: m.to_dict() for label, m in system.models.items()}}
    (tmp_path / "joint.json").write_text(json.dumps(joint))
    loaded = IdentifiedSystem.load(tmp_path / "joint.json")
    test = result.test
    assert loaded.compare(test)["fit_percent"].to_dict() == pytest.approx(system.compare(test)["fit_percent"].to_dict())
    with pytest.raises(CvxidError, match=r"compare takes one equation's model; this system has 2 coupled equations: "
                                         r"use system.compare\(experiment\)"):
        cvxid.compare(system, test)  # (the package's compare, for one equation; it used to raise AttributeError)
    single = system.models["theta"]
    (tmp_path / "one.json").write_text(json.dumps(single.to_dict()))
    assert json.loads((tmp_path / "one.json").read_text())["schema"] == "cvxid.identified/1"
    assert IdentifiedModel.load(tmp_path / "one.json").coefficients == single.coefficients
    with pytest.raises(CvxidError, match="coupled equations: read it with IdentifiedSystem.load"):
        IdentifiedModel.load(tmp_path / "joint.json")


def _raw():
    import tomllib

    return tomllib.loads(SPEC.read_text())


@pytest.mark.parametrize("edit, message", [
    (lambda r: r["model"]["tie"][0].update(left="alpha:gamma"), "'alpha:gamma' is not a column"),
    (lambda r: r["model"]["equation"][1].update(coordinate="theta"), "two [[model.equation]] tables have the coordinate"),
    (lambda r: r["model"].update(equation=r["model"]["equation"][:1]), "needs exactly one [[truth.equation]]"),
    (lambda r: r["model"]["delay"].update(method="taylor"), 'method = "exact"'),
    (lambda r: r["model"].pop("delay"), "missing section [model.delay]"),
    (lambda r: r["model"]["equation"][1].update(names={"k_s": "alpha"}), "'k_s' is given in two equations"),
    (lambda r: r["model"]["equation"][0].update(damping=1.0), "unknown key(s) damping in [model.equation[0]]"),
    (lambda r: r["truth"]["equation"][0].update(coordinate="beta"), "coordinate 'beta' has no [[model.equation]]"),
    (lambda r: r["truth"]["equation"][1].update(input="v"), "must share one input"),
    (lambda r: r["model"]["equation"][0]["library"].update(terms=["theta'", "gamma"]), "gamma"),
    (lambda r: r["fit"].update(estimator="magic"), "estimator"),
    (lambda r: r["model"]["equation"][0].update(input_delay=0.1), "the equations share one input, so give its delay "
                                                                  "once, in [model]"),
    (lambda r: r["model"].update(input_delay={"tau_min": 0.2, "tau_max": 0.1}), "[model.input_delay] needs tau_min < "
                                                                               "tau_max"),
    (lambda r: r["truth"]["equation"][0].update(input_delay=0.1), "[truth.equation[0]] input_delay: the equations "
                                                                  "share one input"),
    (lambda r: r["model"]["equation"][1].update(delay_gain=0.0), "[model.equation[1]] delay_gain must be a finite "
                                                                 "non-zero number"),
    (lambda r: r["model"]["equation"][1].update(input="v"), "[model.equation[1]] input = 'v' is not the input the "
                                                            "[truth] simulates ('u')"),
    (lambda r: r["diagnose"].update(candidates=[]), "[diagnose] candidates is empty"),
    (lambda r: r["diagnose"].update(candidates=["coulomb(beta)"]), "'coulomb(beta)' names no coordinate of the model"),
    (lambda r: r["model"]["equation"][0]["library"].update(select=True), "has select = true, a selection, and "
                                                                        "[fit] estimator = \"lstsq\" selects nothing"),
    (lambda r: r["model"]["tie"].append({"left": "alpha:theta'", "right": "theta:theta'", "factor": 2.0}),
     "[model.tie[2]] contradicts the ties before it"),
])
def test_bad_coupled_specs_are_named(edit, message):
    raw = _raw()
    edit(raw)
    with pytest.raises(CvxidError) as info:
        parse_problem(raw, SPEC.parent)
    assert message in str(info.value)
    assert type(info.value) is CvxidError


def test_bad_coupled_spec_exits_cleanly_from_the_cli(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(SPEC.read_text().replace('left = "alpha:theta\'"', 'left = "alpha:omega"'))
    assert main(["run", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cvxid: error:") and "Traceback" not in err and "alpha:omega" in err


def test_negated_input_and_named_parameters():
    spec = load_problem(SPEC)
    train = spec.experiment("train")
    assert (train.input("-u") == -train.input("u")).all()
    assert spec.truth.physical["k_s"] == 1.3  # "-alpha": minus the theta equation's alpha coefficient
    assert spec.truth.physical["alpha:alpha"] == pytest.approx(2.011579)


def test_joint_selection_drops_terms_the_rig_does_not_have():
    # stlsq on the joint lambda path, noise-free 20 s: theta^3 and alpha^3 go, the rest stays
    raw = _raw()
    raw.pop("diagnose")
    raw["fit"] = {"estimator": "stlsq", "lambdas": {"min": 1e-8, "max": 1e-1, "count": 20}, "window": 1.0}
    for which in ("train", "test"):
        raw["data"][which]["simulate"].update(duration=20.0, noise={"output": 0.0})
    for equation in raw["model"]["equation"]:
        equation["library"]["terms"] += ["theta^3", "alpha^3", "sign(theta')"]
        equation["library"]["select"] = True  # the listed terms are candidates, not given
    result = run(parse_problem(raw, SPEC.parent))
    support = {k for k, v in result.system.coefficients.items() if v != 0}
    for label in ("theta", "alpha"):
        assert {f"{label}:theta'", f"{label}:alpha", f"{label}:alpha'", f"{label}:sign(theta')"} <= support
        assert not {f"{label}:theta^3", f"{label}:alpha^3"} & support
    assert result.system.tau == pytest.approx(0.2, rel=0.01)
    assert result.to_dict()["lambda"] > 0


def _raw_without_friction(train: float):
    """The flexible-joint spec's table with its truth's friction removed (so the starting
    library is the true structure), ``train`` seconds of training, 8 s of test, no
    diagnosis."""
    raw = _raw()
    raw["data"]["train"]["simulate"]["duration"] = train
    raw["data"]["test"]["simulate"]["duration"] = 8.0
    for equation in raw["truth"]["equation"]:
        equation["coefficients"].pop("sign(theta')")
    raw.pop("diagnose")
    return raw


def _without_friction(**fit):
    """:func:`_raw_without_friction` on 30 s, equation error only."""
    raw = _raw_without_friction(30.0)
    raw["fit"] = {"velocity": "savgol", "window": 1.0, **fit}
    return parse_problem(raw, SPEC.parent)


def test_coupled_spec_bootstraps_with_its_ties():
    plain = run(_without_friction())
    boot = run(_without_friction(bootstrap={"samples": 6, "seed": 3}))
    data = boot.to_dict()
    assert data["bootstrap"]["samples"] == 6
    terms = data["bootstrap"]["terms"]
    # every sample keeps the tie, so the mean does; the spread is a real spread
    assert terms["alpha:theta'"]["mean"] == pytest.approx(-terms["theta:theta'"]["mean"], rel=1e-9)
    assert terms["theta:alpha"]["std"] > 0
    # as for one equation, the bootstrap gives the spread and the support; with an exact
    # delay the estimate is the refit at the delay profiled on that support (here: every
    # term, so the fit on all rows), and the ensemble mean lies within three of its standard
    # errors (std / sqrt(6)) of it: blocks of rows span the record's independent stretches, so
    # six samples' mean moves by several % (3.7 % measured; single rows, 1.6 %)
    assert boot.physical["k_s"] == pytest.approx(plain.physical["k_s"], rel=1e-12)
    k_s = terms["theta:alpha"]
    assert abs(-k_s["mean"] - plain.physical["k_s"]) <= 3 * k_s["std"] / np.sqrt(6)
    assert boot.physical["k_s"] == pytest.approx(1.3, rel=0.15)  # equation error: the noise splits k_s and J_eq


def test_coupled_spec_accepts_the_huber_loss():
    robust = run(_without_friction(loss="huber"))
    assert robust.to_dict()["loss"] == "huber"
    coefs = robust.system.coefficients
    assert coefs["alpha:theta'"] == pytest.approx(-coefs["theta:theta'"], rel=1e-9)  # the tie holds
    assert robust.physical["k_s"] == pytest.approx(1.3, rel=0.15)  # equation error (measured -11 %)
    assert robust.physical["B"] == pytest.approx(0.08403, rel=0.02)


def test_coupled_run_reports_the_k_step_fit_of_every_coordinate():
    """The k-step-ahead check of one equation, for N coordinates: each window of 0.1 s
    simulated from the measured states; a well-specified coupled model predicts both
    angles closely, and closer than its free run (which carries the initial-state error)."""
    data = run(_without_friction()).to_dict()
    ahead, free = data["test_k_step_fit_percent"], data["test_fit_percent"]
    assert set(ahead) == {"theta", "alpha"}
    assert min(ahead.values()) > 95
    assert all(ahead[c] >= free[c] - 1 for c in ahead)


FIXTURES = ROOT / "tests" / "fixtures"


@pytest.mark.parametrize("spec, fixture, fits", [
    # model.json files written by the previous release (cvxid.identified/1, cvxid.joint/1) with the
    # free-run test fits its run reported
    ("hidden_friction", "hidden_friction_model_identified_v1.json", {"x": 99.27698364434589}),
    ("flexible_joint", "flexible_joint_model_joint_v1.json", {"theta": 99.90887588161894, "alpha": 99.40978861848362}),
])
def test_model_files_written_by_the_previous_release_load_and_simulate_as_before(spec, fixture, fits):
    system = IdentifiedSystem.load(FIXTURES / fixture)
    test = load_problem(ROOT / "problems" / f"{spec}.toml").experiment("test")
    # both models have a Coulomb term, now simulated with a continuous stick-slip friction (the test data
    # of hidden_friction too): the fits move in the second decimal, no more
    # (from the record's own start, as that release simulated; the estimated start fits at least as well)
    assert system.compare(test, initial="record")["fit_percent"].to_dict() == pytest.approx(fits, abs=0.2)
    estimated = system.compare(test)
    assert (estimated["fit_percent"] >= estimated["record_fit_percent"] - 1e-9).all()


def _lasso_with_extra_terms(test: bool):
    """The flexible joint on 15 s, theta and theta^3 added to both libraries, the inertia tie
    only, selected by the lasso (with or without a test experiment)."""
    raw = _raw()
    raw["data"]["train"]["simulate"]["duration"] = 15.0
    if test:
        raw["data"]["test"]["simulate"]["duration"] = 8.0
    else:
        raw.pop("diagnose")
        raw["data"].pop("test")
    for equation in raw["model"]["equation"]:
        equation["library"]["terms"] += ["theta", "theta^3"]
        equation["library"]["select"] = True
    raw["model"]["tie"] = raw["model"]["tie"][1:]  # the inertia tie only
    raw["fit"] = {"estimator": "lasso", "lambdas": {"min": 1e-4, "max": 1e1, "count": 12}, "window": 2.0}
    return run(parse_problem(raw, SPEC.parent))


def test_coupled_selection_keeps_its_whole_libraries_as_one_equation_does():
    """After the lasso selects each equation's terms, the model keeps its whole libraries,
    the dropped terms at 0 (as one equation's does: the diagnosis may bring one back); the
    free-run fit of the test record is what the refinement reached."""
    result = _lasso_with_extra_terms(test=True)
    libraries = {label: set(m.spec.library.names) for label, m in result.system.models.items()}
    added = {s.term for s in result.refinement.steps}
    assert all({"theta", "theta^3"} <= library for library in libraries.values())
    coefficients = result.system.coefficients
    assert any(coefficients[f"{label}:theta^3"] == 0 for label in libraries)  # something was dropped
    assert {n.partition(":")[2] for n in coefficients} <= set().union(*libraries.values()) | added | {"theta''",
                                                                                                   "alpha''"}
    # no polish, the friction missing from the library: measured theta 95.8 %, alpha 73.5 % (83.5 % and 9.8 % when
    # the selected terms became the libraries and the diagnosis could not bring one back)
    assert min(result.to_dict()["test_fit_percent"].values()) > 70


def test_coupled_selection_without_test_data_cross_validates():
    """No [data.test]: lambda is chosen by blocked 5-fold cross-validation over time (it
    used to be refused for coupled specs and to fall silently to the smallest lambda for one
    equation); the ties hold in every fold."""
    raw = _raw()
    raw.pop("diagnose")
    raw["data"].pop("test")
    raw["data"]["train"]["simulate"].update(duration=20.0, noise={"output": 0.0})
    for equation in raw["truth"]["equation"]:  # the library is the true structure
        equation["coefficients"].pop("sign(theta')")
    for equation in raw["model"]["equation"]:  # ... offered as candidates, so the path selects
        equation["library"]["select"] = True
    raw["fit"] = {"estimator": "stlsq", "lambdas": {"min": 1e-8, "max": 1e-1, "count": 12}, "window": 1.0}
    result = run(parse_problem(raw, SPEC.parent))
    assert np.all(np.isfinite(result.path.validation)) and result.lam > 1e-8
    coefficients = result.system.coefficients
    assert coefficients["alpha:theta'"] == pytest.approx(-coefficients["theta:theta'"], rel=1e-9)
    assert result.physical["k_s"] == pytest.approx(1.3, rel=0.02)


def test_coupled_selection_without_test_data_may_drop_terms():
    result = _lasso_with_extra_terms(test=False)
    assert any(m.coefficients[t] == 0 for m in result.system.models.values() for t in m.spec.library.names)
    coefficients = result.system.coefficients
    assert coefficients["alpha:alpha''"] == pytest.approx(coefficients["theta:theta''"], rel=1e-9)


def test_a_coupled_spec_declares_its_own_effect_and_the_diagnosis_adds_it():
    """[diagnose.effects] in a coupled spec: the rig's hidden motor-side friction written as
    the user's own effect (a smooth sign, as a user might) is the only candidate, ranked and
    added to both equations; 30 s of training, equation error only."""
    raw = _raw()
    raw["data"]["train"]["simulate"]["duration"] = 30.0
    raw["data"]["test"]["simulate"]["duration"] = 8.0
    raw["diagnose"] = {"refine": True, "candidates": ["motor_friction"],
                       "effects": {"motor_friction": {"term": "tanh(200 theta')", "meaning": "the motor's dry friction"}}}
    spec = parse_problem(raw, SPEC.parent)
    assert all("motor_friction" in s.effects for s in spec.system.equations.values())
    result = run(spec)
    steps = result.refinement.steps
    assert [s.added for s in steps] == ["motor_friction"]
    assert steps[0].fit_before is None  # the starting model cannot be simulated: its equation-error inertia is 0
    assert steps[0].simulation_error_after < 0.05  # with the friction it can, and fits (measured 0.012)
    assert {"theta:tanh(200 * theta')", "alpha:tanh(200 * theta')"} <= set(result.system.coefficients)
    with pytest.raises(CvxidError, match="unknown term or effect 'motor'"):
        raw["diagnose"]["candidates"] = ["motor"]
        parse_problem(raw, SPEC.parent)


def test_a_coupled_spec_searches_the_order_of_every_polynomial_library():
    """[fit] orders on a coupled spec (it was refused): each equation's polynomial library
    is cut to each order, the system scored on the test record, the least test error kept;
    the ties hold at every order, and each equation keeps its extra terms."""
    raw = _raw_without_friction(20.0)
    raw["model"]["equation"][0]["library"] = {"order": 3, "cross": False, "extra": ["alpha", "alpha'"]}
    raw["model"]["equation"][1]["library"] = {"order": 3, "cross": False, "extra": ["theta'"]}
    raw["fit"] = {"estimator": "lasso", "velocity": "savgol", "window": 1.0, "orders": {"min": 1, "max": 3},
                  "lambdas": {"min": 1e-6, "max": 1e1, "count": 20}}
    result = run(parse_problem(raw, SPEC.parent))
    table = result.order_search.table
    assert list(table.index) == [1, 2, 3]
    best = result.order_search.best_order
    assert table.loc[best, "test_mse"] == table["test_mse"].min()
    for order, coefficients in result.order_search.coefficients.items():  # every order kept the tie
        assert coefficients["alpha:theta'"] == pytest.approx(-coefficients["theta:theta'"], rel=1e-9)
        assert ("theta:theta^3" in coefficients.index) == (order >= 3)
        assert "alpha:theta'" in coefficients.index and "theta:alpha'" in coefficients.index
    libraries = {label: m.spec.library.names for label, m in result.system.models.items()}
    assert ("theta^2" in libraries["theta"]) == (best >= 2) and ("theta^3" in libraries["theta"]) == (best >= 3)
    assert {"alpha", "alpha'"} <= set(libraries["theta"]) and "theta'" in libraries["alpha"]
    coefficients = result.system.coefficients
    assert coefficients["alpha:alpha''"] == pytest.approx(coefficients["theta:theta''"], rel=1e-9)
    assert result.physical["k_s"] == pytest.approx(1.3, rel=0.15)  # equation error at noise 0.001 (measured -7 %)
    assert result.system.tau == pytest.approx(0.2, rel=0.02)


def test_orders_on_a_coupled_spec_without_a_polynomial_library_are_refused():
    raw = _raw()
    raw["fit"]["orders"] = {"min": 1, "max": 3}
    with pytest.raises(CvxidError, match=r"\[fit\] orders searches an order's polynomial library"):
        parse_problem(raw, SPEC.parent)


def test_a_coupled_selection_runs_stability_selection_on_the_same_stretches_of_each_equation():
    """Stability selection for N > 1 (it was refused): on halves of the record, each the same
    stretches of time of both equations, the true coupling terms are kept on most halves and
    the spurious cubic ones on few; 15 s noise 0.001, the friction removed from the truth."""
    raw = _raw_without_friction(15.0)
    for equation in raw["model"]["equation"]:
        equation["library"]["terms"] += ["theta", "theta^3", "theta'^3"]
        equation["library"]["select"] = True
    raw["fit"] = {"estimator": "adaptive_lasso", "window": 1.0, "velocity": "savgol"}  # stability: the default
    result = run(parse_problem(raw, SPEC.parent))
    probability = result.stability.inclusion
    assert min(probability[c] for c in ("theta:alpha", "theta:alpha'", "alpha:theta'")) >= 0.7  # (measured 0.85-1)
    assert max(probability[c] for c in ("theta:theta^3", "alpha:theta^3", "theta:theta'^3", "alpha:theta'^3")) < 0.5
    assert result.to_dict()["stability"]["samples"] == 20


def _with_candidates(estimator: str):
    """The flexible joint on 10 s, theta^3 and the friction offered to both equations (to
    select, not given; listed for "lstsq"), polished by output error."""
    raw = _raw()
    raw["data"]["train"]["simulate"]["duration"] = 10.0
    raw["data"]["test"]["simulate"]["duration"] = 8.0
    raw.pop("diagnose")
    for equation in raw["model"]["equation"]:
        equation["library"]["terms"] += ["theta^3", "sign(theta')"]
        equation["library"]["select"] = estimator != "lstsq"
    raw["fit"] = {"estimator": estimator, "window": 1.0, "velocity": "savgol", "refine": "output_error"}
    return run(parse_problem(raw, SPEC.parent))


TRUE_JOINT = {f"{label}:{term}" for label in ("theta", "alpha")
              for term in ("theta'", "alpha", "alpha'", "sign(theta')", f"{label}''")}


@pytest.mark.slow
def test_a_coupled_spec_selects_its_terms_by_simulation_error():
    """estimator = "stepwise_oe" for N > 1 (it was refused): the search over the columns of
    both equations adds the friction to both and no cubic stiffness, the ties hold, and the
    final polish recovers the stiffness and the delay (measured k_s -0.5 %, tau -0.06 %)."""
    result = _with_candidates("stepwise_oe")
    coefficients = result.system.coefficients
    assert {n for n, c in coefficients.items() if c != 0} == TRUE_JOINT
    assert coefficients["alpha:theta'"] == pytest.approx(-coefficients["theta:theta'"], rel=1e-9)
    assert result.physical["k_s"] == pytest.approx(1.3, rel=0.02)
    assert result.physical["tau"] == pytest.approx(0.2, rel=0.005)
    assert result.to_dict()["stepwise"]["history"][-1]["action"] == "polish at the sample step"  # (COUPLED_POLISH)


def test_the_pruning_removes_a_coupled_systems_spurious_terms():
    """prune_by_simulation for N > 1: least squares keeps a small theta^3 in both equations;
    the simulation error does not need it, so both go, and the pruned model keeps its whole
    libraries (theta^3 at 0) and its simulation error."""
    from cvxid.identify.stepwise import prune_by_simulation

    result = _with_candidates("lstsq")
    assert all(result.system.coefficients[f"{label}:theta^3"] != 0 for label in ("theta", "alpha"))
    pruning = prune_by_simulation(result.polish, result.train, ["theta:theta^3", "alpha:theta^3"])
    assert sorted(pruning.removed) == ["alpha:theta^3", "theta:theta^3"]
    system = pruning.polish.system
    assert all(system.coefficients[f"{label}:theta^3"] == 0 for label in ("theta", "alpha"))
    assert all("theta^3" in m.spec.library.names for m in system.models.values())
    assert pruning.polish.rms_after < 1.01 * result.polish.rms_after


def test_a_coupled_diagnosis_takes_one_coordinates_effect_by_its_printed_name():
    """[diagnose] candidates = ["coulomb(theta)"] (the name the ranking prints; it was
    refused as an unknown function): that coordinate's friction only; an unknown
    coordinate is still refused."""
    raw = _raw()
    raw["data"]["train"]["simulate"]["duration"] = 20.0
    raw["data"]["test"]["simulate"]["duration"] = 8.0
    raw["fit"] = {"velocity": "savgol", "window": 1.0}
    raw["diagnose"] = {"refine": True, "candidates": ["coulomb(theta)", "offset"]}
    result = run(parse_problem(raw, SPEC.parent))
    assert list(result.diagnosis.ranking.index) == ["coulomb(theta)", "offset"]
    assert [s.added for s in result.refinement.steps] == ["coulomb(theta)"]
    assert result.refinement.steps[0].columns == ("theta:sign(theta')", "alpha:sign(theta')")
    raw["diagnose"]["candidates"] = ["coulomb(beta)"]
    with pytest.raises(CvxidError, match="beta"):
        parse_problem(raw, SPEC.parent)


def test_the_truth_of_a_coupled_run_is_the_simulated_one_where_the_model_estimates_or_assumes():
    """Outside check: with the gains estimated, the truth's gains showed as -0 (read from
    the model's specs), and a model's input delay showed as the truth's when the truth had
    none.  And a velocity fed back ([truth.delay] signal = "x'") simulates (it was refused)."""
    import tomllib

    from .test_simulation_diagnosis import COUPLED

    raw = tomllib.loads(COUPLED)
    raw["truth"]["delay"]["signal"] = raw["model"]["delay"]["signal"] = "x'"
    raw["model"]["equation"][0]["library"]["terms"].append("x^3")
    for equation in raw["model"]["equation"]:
        equation.pop("delay_gain")  # estimated
    raw["model"]["input_delay"] = 0.02  # assumed by the model, absent from the truth
    spec = parse_problem(raw, ROOT)
    assert spec.truth.physical["x:gain"] == 1.0 and spec.truth.physical["y:gain"] == 0.5
    assert "tau_u" not in spec.truth.physical
    raw["model"].pop("input_delay")
    result = run(parse_problem(raw, ROOT))
    assert result.physical["x:gain"] == pytest.approx(1.0, rel=0.03) and result.physical["tau"] == pytest.approx(
        0.15, rel=0.02)  # (measured +- 1.1 %, +0.2 %)


def test_the_order_search_keeps_the_terms_a_tie_names():
    """Outside check: a tie between the cubic stiffnesses of two equations was dropped, with
    its terms, at every order below 3 (the run said nothing); a tie says its terms belong, so
    they stay at every order and the tie holds."""
    import tomllib

    from .test_simulation_diagnosis import COUPLED

    raw = tomllib.loads(COUPLED)
    raw["truth"]["equation"][1]["coefficients"]["y^3"] = 3.0
    raw["model"]["equation"][0]["library"] = {"order": 3, "cross": False, "extra": ["y"]}
    raw["model"]["equation"][1]["library"] = {"order": 3, "cross": False, "extra": ["x"]}
    raw["model"]["tie"] = [{"left": "x:x^3", "right": "y:y^3", "factor": 1.0}]
    raw["fit"] = {"estimator": "adaptive_lasso", "orders": {"min": 1, "max": 2}, "velocity": "savgol"}
    result = run(parse_problem(raw, ROOT))
    assert result.system.ties == (("x:x^3", "y:y^3", 1.0),)
    for coefficients in result.order_search.coefficients.values():
        assert coefficients["x:x^3"] == pytest.approx(coefficients["y:y^3"], rel=1e-9)
    assert result.system.coefficients["x:x^3"] == pytest.approx(3.0, rel=0.02)


def test_a_truth_that_cannot_be_simulated_names_its_tables():
    import tomllib

    from .test_simulation_diagnosis import COUPLED

    raw = tomllib.loads(COUPLED)
    raw["truth"]["equation"][0]["coefficients"].pop("x^3")  # (the hardening would bound the motion)
    raw["truth"]["equation"][0]["delay_gain"] = 30.0  # an unstable loop
    with pytest.raises(CvxidError, match=r"spec: \[data.train.simulate\] the \[truth\] system cannot be simulated"):
        run(parse_problem(raw, ROOT))


def test_a_coupled_inertia_at_its_bound_names_the_equations_input_and_a_diverged_polish_says_so(tmp_path):
    """A seventh outside check: the flexible joint on 20 s with its hidden friction and no
    diagnosis (the equation error's inertias at 0): the warning advised ``[model] input``,
    which a coupled spec does not have, and the polish printed ``simulation RMS inf ->
    1e+06``, result.json ``rms_after`` 1000000.0, the fill of a diverged simulation read as
    an RMS."""
    raw = _raw()
    raw["data"]["train"]["simulate"]["duration"] = 20.0
    raw["data"]["test"]["simulate"]["duration"] = 10.0
    raw.pop("diagnose")
    result = run(parse_problem(raw, SPEC.parent))
    assert result.physical["J_eq"] < 1e-6  # (the record's equation error: the inertia at its bound)
    said = [w for w in result.warnings if "at its lower bound" in w]
    assert said and all("in the [[model.equation]] of '" in w and "[model] input" not in w for w in said), said
    assert "simulation RMS diverged -> diverged" in result.summary()
    from cvxid.app.report import plain

    assert plain(result.to_dict())["polish"]["rms_after"] is None  # (null in result.json)
