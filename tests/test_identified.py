"""Identified models: JSON round trip, corrupted files, python-control export."""

import json

import control
import numpy as np
import pytest

from cvxid import CvxidError
from cvxid.diagnosis.refine import refit
from cvxid.identified import IdentifiedModel
from cvxid.simulate import simulate

from .test_diagnostics import experiments, linear_model


@pytest.fixture(scope="module")
def model():
    train, _ = experiments("cubic_stiffness")
    spec = linear_model()
    from cvxid.diagnosis.candidates import with_effect

    return refit(with_effect(spec, "cubic_stiffness"), train, ["x''", "x", "x'", "x^3"], None)


def test_json_round_trip_simulates_identically(model, tmp_path):
    path = tmp_path / "model.json"
    model.save(path)
    again = IdentifiedModel.load(path)
    _, test = experiments("cubic_stiffness")
    a, _ = model.simulate(test, 0.1, 0.0)
    b, _ = again.simulate(test, 0.1, 0.0)
    assert np.array_equal(a, b, equal_nan=True)
    assert again.equation() == model.equation()
    assert "pickle" not in path.read_text()
    # what is estimated and what selected comes back too (a refit or a diagnosis reads it)
    assert again.spec.listed == model.spec.listed and again.spec.keep_linear == model.spec.keep_linear
    assert [c.penalty for c in again.spec.columns] == [c.penalty for c in model.spec.columns]


@pytest.mark.parametrize(
    "corrupt, message",
    [
        (lambda d: d.update(schema="other/9"), "not a cvxid model file"),
        (lambda d: d.pop("coefficients"), "incomplete or corrupted"),
        (lambda d: d["coefficients"].update({"x^9": 1.0}), "unknown columns"),
        (lambda d: d["model"].update(library=["x", "bogus term!"]), "cannot read term .bogus term!"),
        (lambda d: d["model"]["delay"].update(history="yesterday"), "history must be"),
    ],
)
def test_corrupted_model_files_are_named(model, tmp_path, corrupt, message):
    data = model.to_dict()
    corrupt(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(CvxidError, match=message):
        IdentifiedModel.load(path)


def test_non_json_and_missing_files(tmp_path):
    (tmp_path / "x.json").write_text("{ not json")
    with pytest.raises(CvxidError, match="not a JSON model file"):
        IdentifiedModel.load(tmp_path / "x.json")
    (tmp_path / "y.json").write_text("[1, 2]")
    with pytest.raises(CvxidError, match="not a JSON model file"):
        IdentifiedModel.load(tmp_path / "y.json")
    with pytest.raises(CvxidError, match="not found"):
        IdentifiedModel.load(tmp_path / "z.json")


def test_linearised_step_response_matches_within_the_pade_error(model):
    # the linear part of the model (the cubic term vanishes at rest) with a long delay,
    # simulated by cvxid's delay integrator
    linear = type(model)(model.spec, dict(model.coefficients, **{"x^3": 0.0}), tau=0.3)
    t = np.linspace(0, 8, 8001)
    exact, _ = simulate(linear.system(history="initial"), t, lambda s: np.ones_like(s), 0.0, 0.0)
    errors = []
    for order in (1, 2, 4, 8):
        _, y = control.step_response(linear.linearized_tf(order), t)
        errors.append(float(np.abs(y - exact).max()))
    assert errors[-1] < 1e-6 * np.abs(exact).max()
    assert errors[0] > errors[1] > errors[2] > errors[3]  # the gap is the Padé error


def test_nonlinear_export_simulates_like_cvxid(model):
    t = np.linspace(0, 5, 5001)
    force = 2 * np.sin(3 * t)
    ours, _ = simulate(model.system(history="initial"), t, force, 0.0, 0.0)
    nl = model.to_control(8)
    resp = control.input_output_response(nl, t, force, X0=np.zeros(nl.nstates), solve_ivp_kwargs={"rtol": 1e-9, "atol": 1e-11})
    assert np.abs(resp.outputs - ours).max() < 1e-4 * np.abs(ours).max()


def test_a_dry_friction_is_left_out_of_the_linearisation_and_said():
    """A fifth outside check: hidden_friction's model linearised to a damping of 8e5 (the
    central difference of 0.8 sign(x') with a step of 1e-6), with no word."""
    from cvxid import CvxidWarning
    from cvxid.model.equation import ModelSpec
    from cvxid.model.library import Library
    from cvxid.model.terms import parse_term

    spec = ModelSpec(Library([parse_term(n) for n in ("x", "x'", "sign(x')", "x'|x'|")]))
    model = IdentifiedModel(spec, {"x''": 1.0, "x": 6.0, "x'": 0.4, "sign(x')": 0.8, "x'|x'|": 0.3})
    with pytest.warns(CvxidWarning, match=r"sign\(x'\) has no finite derivative at rest \(a jump or an infinite "
                                          r"slope at 0\): left out"):
        tf = model.linearized_tf()
    assert np.allclose(tf.den[0][0], [1.0, 0.4, 6.0], atol=1e-6)  # x'|x'| has slope 0 at rest: not a jump
    assert tf.input_labels == ["f"] and tf.output_labels == ["x"]  # as to_nlsys names them
    root = parse_term("sign(x')*abs(x')^0.5")  # an infinite slope at rest (it added 800 to the damping)
    steep = IdentifiedModel(ModelSpec(Library([parse_term("x"), parse_term("x'"), root])),
                            {"x''": 1.0, "x": 6.0, "x'": 0.4, root.name: 0.8})
    with pytest.warns(CvxidWarning, match="no finite derivative at rest"):
        assert np.allclose(steep.linearized_tf().den[0][0], [1.0, 0.4, 6.0], atol=1e-6)


def test_the_table_lists_the_model_s_terms_and_the_truth_s_not_every_dropped_candidate():
    """A fifth outside check: a selected library's table held 12 rows of "0 NaN" in 17."""
    from cvxid.model.equation import ModelSpec
    from cvxid.model.library import Library

    spec = ModelSpec(Library(["x", "x'", "x^2", "x^3", "x'^3"]))
    model = IdentifiedModel(spec, {"x''": 1.0, "x": 6.0, "x'": 0.4, "x^2": 0.0, "x^3": 0.0, "x'^3": 0.0})
    assert list(model.table().index) == ["m", "x", "x'"]
    table = model.table({"m": 1.0, "x": 6.0, "x'": 0.4, "x^3": 2.0})  # a true term the model set to 0: shown
    assert list(table.index) == ["m", "x", "x'", "x^3"] and table.loc["x^3", "error %"] == -100
    # a seventh outside check: a term the truth lacks read NaN where its true value is 0
    spurious = IdentifiedModel(spec, {"x''": 1.0, "x": 6.0, "x'": 0.4, "x^2": 0.3, "x^3": 0.0, "x'^3": 0.0})
    table = spurious.table({"m": 1.0, "x": 6.0, "x'": 0.4})
    assert table.loc["x^2", "truth"] == 0.0 and np.isnan(table.loc["x^2", "error %"])
