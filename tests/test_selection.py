"""Selecting terms on a λ path: the adaptive lasso's weights and the support they restore,
a grid extended past an open edge (or a warning), and the held-out benchmark's selection
mode."""

import warnings

import numpy as np
import pytest

import cvxid.identify.path as path_module
from cvxid import Path, Problem
from cvxid.errors import CvxidWarning
from cvxid.identify.path import select
from cvxid.app.run import run
from cvxid.spec.load import load_problem
from cvxid.tools.heldout import _selected, draw, run_one, selection_library, write


def _irrepresentable(seed: int, a: float = 0.66, n: int = 2000):
    """``y = x1 + x2`` and a third column ``a (x1 + x2) + noise`` that correlates with
    both more than they with each other (``2 a > 1``: the lasso's irrepresentable condition
    fails, so its path may never hold {x1, x2} alone)."""
    rng = np.random.default_rng(seed)
    x1, x2, e, w = rng.standard_normal((4, n))
    x3 = a * (x1 + x2) + np.sqrt(1 - 2 * a * a) * e
    return np.column_stack([x1, x2, x3]), x1 + x2 + 0.1 * w


def test_adaptive_weights_divide_by_the_least_squares_size():
    P, y = _irrepresentable(1)
    P = np.column_stack([P, np.ones(P.shape[0])])
    problem = Problem.from_arrays(P, y, ["a", "b", "c", "free"], weights=[1, 1, 1, 0])
    ls = np.abs(problem.refit(np.ones(4, bool)).scaled)
    adaptive = problem.adaptive()
    top = ls[:3].max()
    assert adaptive.penalties[:3] == pytest.approx(top / ls[:3], rel=1e-3)  # (a negligible ridge)
    assert adaptive.penalties[:3].min() == pytest.approx(1.0) and adaptive.penalties[3] == 0.0
    assert adaptive.penalties[2] > 2.0  # the redundant column (least squares: ~0) is penalised hardest


def test_adaptive_weights_survive_a_duplicated_column():
    """Exactly collinear columns share their coefficient (the ridge), so the true columns keep
    small weights instead of every column getting the cap."""
    P, y = _irrepresentable(2)
    P = np.column_stack([P, P[:, 0]])
    with pytest.warns(CvxidWarning, match="rank-deficient"):
        problem = Problem.from_arrays(P, y, ["a", "b", "c", "a again"])
    weights = problem.adaptive().penalties
    assert np.all(np.isfinite(weights)) and weights.max() < 1e4
    assert weights[0] == pytest.approx(weights[3], rel=1e-6) and weights[1] == pytest.approx(1.0)
    fits = Path.compute(problem, np.logspace(-6, 1, 30), estimator="adaptive_lasso").fits
    assert any(f.support.tolist() == [True, True, False, True] for f in fits)


def test_a_grid_with_repeated_lambdas_is_selected_on_its_distinct_values():
    problem, validate = _weak_term()
    path, best = select(problem, [0.1, 0.1, 0.1, 1.0, 10.0], validate)
    assert best.support[1] and len(set(path.lambdas)) == len(path.lambdas)  # extended down to where "weak" enters


@pytest.mark.parametrize("seed", [0, 7])
def test_adaptive_lasso_finds_a_support_the_plain_lasso_path_misses(seed):
    P, y = _irrepresentable(seed)
    problem = Problem.from_arrays(P, y, ["a", "b", "c"])
    lambdas = np.logspace(-6, 1, 60)
    true = (True, True, False)
    plain = {tuple(f.support) for f in Path.compute(problem, lambdas, estimator="lasso").fits}
    adaptive = {tuple(f.support) for f in Path.compute(problem, lambdas, estimator="adaptive_lasso").fits}
    assert true not in plain
    assert true in adaptive


def _weak_term(seed: int = 3, n: int = 4000):
    """A strong and a weak true term: the weak one enters only at a small lambda."""
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((2 * n, 3))
    y = X[:, 0] + 0.01 * X[:, 1] + 1e-4 * rng.standard_normal(2 * n)
    problem = Problem.from_arrays(X[:n], y[:n], ["strong", "weak", "spurious"])
    return problem, (lambda c: X[n:] @ c - y[n:])


def test_a_grid_that_ends_above_a_needed_term_is_extended_down():
    problem, validate = _weak_term()
    grid = np.logspace(-1, 2, 10)
    with warnings.catch_warnings():
        warnings.simplefilter("error", CvxidWarning)
        path, best = select(problem, grid, validate)
    assert best.lam < grid.min()
    assert list(best.support[:2]) == [True, True]
    assert best.coefficients[1] == pytest.approx(0.01, rel=1e-2)
    assert len(path.fits) > grid.size


def test_a_grid_edge_still_open_after_the_extensions_is_a_warning(monkeypatch):
    monkeypatch.setattr(path_module, "EXTENSIONS", 0)
    problem, validate = _weak_term()
    with pytest.warns(CvxidWarning, match="chose the bottom of its grid") as caught:
        _, best = select(problem, np.logspace(-1, 2, 10), validate)
    assert best.lam >= 0.1 and not best.support[1]
    assert "lambdas a wider range" in str(caught[0].message)


def test_an_edge_where_the_path_ends_is_an_answer_not_an_open_edge():
    """No candidate left at the top: nothing to gain past it, no extension, no warning."""
    problem, _ = _weak_term()
    prefers_nothing = lambda c: np.full(40, 1.0 + np.abs(c[1:]).sum())  # noqa: E731
    with warnings.catch_warnings():
        warnings.simplefilter("error", CvxidWarning)
        path, best = select(problem, np.logspace(-2, 2, 12), prefers_nothing)
    assert len(path.fits) == 12 and best is path.fits[0] and path.open_edge() is None
    assert not best.support.any()


def test_the_selection_mode_lists_no_term_and_scores_the_support(tmp_path):
    o = draw(5, "coulomb", noise=0.01, duration=6.0)
    spec = load_problem(write(o, tmp_path, mode="selection", fit={"estimator": "adaptive_lasso"}))
    names = spec.model.library.names
    assert set(names) == set(selection_library()) and len(names) == 18
    assert not spec.model.listed and spec.fit.estimator == "adaptive_lasso"
    assert set(o.terms) <= set(names)
    exact = {"coefficients": {n: (1.0 if n in o.terms else 0.0) for n in names}}
    assert _selected(exact, o) == {"support recovered": True, "missed": "", "spurious": ""}
    wrong = {"coefficients": {**exact["coefficients"], "x'": 0.0, "x^2 x'": 0.3}}
    assert _selected(wrong, o) == {"support recovered": False, "missed": "x'", "spurious": "x^2 x'"}


def test_on_a_held_out_system_the_default_finds_the_support_the_plain_lasso_misses():
    """Tuning seed 1 (no hidden effect, noise 0.01, 8 s, 18 candidates): the documented
    defaults (adaptive lasso, 1se) keep exactly x, x', x^3; the plain lasso with the min rule
    keeps spurious velocity terms beside them (the selection itself: no pruning after it)."""
    default = run_one(1, "none", 0.01, 8.0, mode="selection", known_gain=True)
    plain = run_one(1, "none", 0.01, 8.0, mode="selection", known_gain=True,
                    fit={"estimator": "lasso", "selection": "min", "prune": False})
    assert default["status"] == "ok" and default["support recovered"], default
    assert abs(default["tau error %"]) < 2.0 and default["worst other %"] < 5.0
    assert not plain["support recovered"] and plain["spurious"] and not plain["missed"]


@pytest.mark.parametrize("seed, effect, stand_in", [(1, "coulomb", "x'^3"), (2, "quadratic_damping", "x'^3")])
def test_the_diagnosis_selects_the_library_anew_beside_the_effect_it_adds(tmp_path, seed, effect, stand_in):
    """Tuning seeds, noise 0.01, the order-3 polynomial without the hidden effect's term:
    the first selection keeps a velocity term standing in for the missing effect; once the
    diagnosis adds the effect, the library is selected again beside it and the stand-in
    leaves: the final model has exactly the true terms."""
    o = draw(seed, effect, 0.01, 8.0)
    result = run(write(o, tmp_path, mode="selection_diagnosis", known_gain=True))
    library = set(selection_library())
    first = next(f for f in result.path.fits if f.lam == result.lam)
    chosen = {n for n, k in zip(result.path.names, first.support) if k} & library
    final = {n for n, c in result.system.coefficients.items() if c != 0.0} & library
    assert stand_in in chosen and chosen != set(o.terms)
    assert [s.added for s in result.refinement.steps] == [effect]
    assert final == set(o.terms)


def test_the_linear_stiffness_and_damping_are_kept_and_a_delay_cannot_stand_in(tmp_path):
    """Tuning seed 4 with Coulomb friction, noise 0.01, 18 candidates: with x' a candidate
    the selection dropped the damping, the delay stood in for it (b x(t - tau) = b x - b
    tau x' + ...: tau 97 % off) and two velocity terms joined; kept (the default), the
    true support and the delay within 1 %.  ``keep_linear = false`` makes them candidates."""
    o = draw(4, "coulomb", 0.01, 8.0)
    path = write(o, tmp_path, mode="selection", known_gain=True)
    spec = load_problem(path)
    penalties = {c.name: c.penalty for c in spec.model.columns}
    assert penalties["x"] == penalties["x'"] == 0.0 and penalties["x^3"] == penalties["sign(x')"] == 1.0
    result = run(spec)
    kept = {n for n, c in result.model.coefficients.items() if c != 0.0} & set(selection_library())
    assert kept == set(o.terms)
    assert result.model.physical["tau"] == pytest.approx(o.tau, rel=0.01)
    text = path.read_text().replace("[model.library]\n", "[model.library]\nkeep_linear = false\n")
    path.write_text(text)
    assert {c.name: c.penalty for c in load_problem(path).model.columns}["x'"] == 1.0
