"""Stability selection: the terms a selector keeps on most halves of the record."""

import json

import numpy as np
import pytest

from cvxid import CvxidError
from cvxid.identify.problem import Problem
from cvxid.identify.selection import Selection, StabilitySettings
from cvxid.regression.regression import Regression
from cvxid.spec.load import load_problem
from cvxid.tools.heldout import draw, run_one, write


def _regression(rng, n=2000, disturbance=0.5):
    """Three true columns, two of noise, and one that explains a disturbance of the first
    tenth of the record only (none in a test record: ``disturbance = 0``)."""
    P = rng.standard_normal((n, 6))
    local = np.zeros(n)
    local[: n // 10] = rng.standard_normal(n // 10)
    P[:, 5] = local + 0.05 * rng.standard_normal(n)
    p = P[:, :3] @ np.array([1.0, -2.0, 0.5]) + disturbance * local + 0.1 * rng.standard_normal(n)
    names = ("a", "b", "c", "noise1", "noise2", "local")
    return Regression(P, p, names, ("library",) * 6, np.ones(6))


def _check(reg):
    return lambda c: reg.P @ c - reg.p


@pytest.mark.parametrize("seed", [0, 1])
def test_the_true_terms_are_kept_on_every_half_and_the_others_on_few(seed):
    reg, test = _regression(np.random.default_rng(seed)), _regression(np.random.default_rng(seed + 100), disturbance=0)
    plain = Selection("adaptive_lasso", rule="1se").choose(Problem.from_regression(reg), _check(test))
    assert plain.stability is None  # off unless asked
    stable = Selection("adaptive_lasso", rule="1se", stability=StabilitySettings()).choose(
        Problem.from_regression(reg), _check(test))
    inclusion = stable.stability.inclusion
    assert (inclusion[["a", "b", "c"]] == 1.0).all()
    assert inclusion[["noise1", "noise2", "local"]].max() < 0.3  # measured 0 and 0
    assert list(stable.keep) == [True, True, True, False, False, False]
    assert "Stability selection (20 halves of 10 blocks, candidates kept at >= 0.7): a, b, c" in repr(stable.stability)
    assert stable.stability.accepted
    # without a test record there is nothing to check a stable support by: the whole record's choice
    assert Selection(stability=StabilitySettings()).choose(Problem.from_regression(reg), folds=5).stability is None


def test_a_column_zero_on_some_halves_skips_them_instead_of_failing():
    reg, test = _regression(np.random.default_rng(2)), _regression(np.random.default_rng(3))
    late = reg.P.copy()
    late[: reg.shape[0] // 2, 2] = 0.0  # the third term's input starts half-way through the record
    reg = Regression(late, late[:, :3] @ np.array([1.0, -2.0, 0.5]), reg.names, reg.groups, reg.penalties)
    stable = Selection(stability=StabilitySettings()).choose(Problem.from_regression(reg), _check(test))
    assert stable.stability.inclusion["a"] == 1.0  # the halves that could be fitted


def test_the_settings_are_checked_by_name():
    with pytest.raises(CvxidError, match="stability threshold must lie in 0.5 … 1"):
        StabilitySettings(threshold=0.3)
    with pytest.raises(CvxidError, match="stability blocks must be an even whole number from 4 to 100"):
        StabilitySettings(blocks=5)
    reg = _regression(np.random.default_rng(1), n=30)
    with pytest.raises(CvxidError, match="30 regression rows cannot be cut into 20 blocks"):
        Selection(stability=StabilitySettings(blocks=20)).choose(Problem.from_regression(reg), _check(reg))


def test_a_spec_turns_it_off_or_sets_it_and_bad_values_name_the_field(tmp_path):
    oscillator = draw(0, "none", noise=0.01, duration=8.0)
    path = write(oscillator, tmp_path / "s", mode="selection", known_gain=True)
    assert load_problem(path).fit.stability == StabilitySettings()  # on by default
    text = path.read_text()
    path.write_text(text.replace("[fit]\n", "[fit]\nstability = false\n"))
    assert load_problem(path).fit.stability is None
    path.write_text(text.replace("[fit]\n", "[fit]\nstability = { samples = 40, threshold = 0.8 }\n"))
    assert load_problem(path).fit.stability == StabilitySettings(samples=40, threshold=0.8)
    path.write_text(text.replace("[fit]\n", "[fit]\nestimator = \"stlsq\"\n"))
    assert load_problem(path).fit.stability is None  # the paper's thresholding keeps its own rule unless asked
    assert load_problem("paper_duffing_exact").fit.stability is None
    path.write_text(text.replace("[fit]\n", "[fit]\nstability = { threshold = 0.2 }\n"))
    with pytest.raises(CvxidError, match=r"\[fit.stability\] threshold"):
        load_problem(path)
    path.write_text(text.replace("[fit]\n", "[fit]\nestimator = \"lstsq\"\nstability = true\n"))
    with pytest.raises(CvxidError, match="estimator = 'lstsq' selects nothing"):
        load_problem(path)
    path.write_text(text.replace("[fit]\n", "[fit]\nstability = \"yes\"\n"))
    with pytest.raises(CvxidError, match="stability is true, false or a table"):
        load_problem(path)
    # a seventh outside check: stability asked for beside a bootstrap was dropped without a word
    path.write_text(text.replace("[fit]\n", "[fit]\nstability = { samples = 10 }\nbootstrap = { samples = 6 }\n"))
    with pytest.raises(CvxidError, match="stability and bootstrap both select on resampled records.*remove one"):
        load_problem(path)
    path.write_text(text.replace("[fit]\n", "[fit]\nbootstrap = { samples = 6 }\n"))  # the default: no stability
    assert load_problem(path).fit.bootstrap.samples == 6


def test_on_a_held_out_system_it_drops_the_spurious_term_the_whole_record_kept(tmp_path):
    # tuning seed 5, a hidden Coulomb friction, noise 0.01, 18 candidate terms: without
    # stability selection the adaptive lasso keeps x'|x'| beside the true terms (measured);
    # the stable support passes the 1se rule's bound and is taken (the selection itself: no
    # pruning by simulation error after it)
    plain = run_one(5, "coulomb", 0.01, 8.0, mode="selection", known_gain=True, fit={"stability": False,
                                                                                       "prune": False})
    assert plain["status"] == "ok" and not plain["support recovered"] and plain["spurious"] == "x'|x'|"
    stable = run_one(5, "coulomb", 0.01, 8.0, mode="selection", known_gain=True, keep=tmp_path,
                     fit={"prune": False})
    assert stable["status"] == "ok" and stable["support recovered"], (stable["missed"], stable["spurious"])
    (folder,) = tmp_path.iterdir()
    result = json.loads((folder / "result.json").read_text())
    inclusion, accepted = result["stability"]["inclusion"], result["stability"]["accepted"]
    true = draw(5, "coulomb", noise=0.01, duration=8.0).terms
    assert "sign(x')" in true and accepted and min(inclusion[t] for t in true) >= 0.7 > inclusion["x'|x'|"]


def test_a_stable_support_the_test_record_rejects_is_not_taken(tmp_path):
    # tuning seed 0, no hidden effect, noise 0.01: the halves keep exactly x, x', x^3, but
    # x^3 x'^2 lowers the test record's equation error beyond the 1se bound (it stands in
    # for the velocity estimate's error in both records), so the whole record's choice stays
    # (the selection itself: the pruning by simulation error after it removes x^3 x'^2)
    stable = run_one(0, "none", 0.01, 8.0, mode="selection", known_gain=True, keep=tmp_path, fit={"prune": False})
    pruned = run_one(0, "none", 0.01, 8.0, mode="selection", known_gain=True)
    assert pruned["support recovered"], (pruned["missed"], pruned["spurious"])
    (folder,) = tmp_path.iterdir()
    result = json.loads((folder / "result.json").read_text())
    inclusion = result["stability"]["inclusion"]
    assert not result["stability"]["accepted"] and inclusion["x^3 x'^2"] < 0.7 <= inclusion["x'"]
    assert stable["spurious"] == "x^3 x'^2"  # the whole record's selection, reported as such
