"""Coefficients tied across equations: one joint cvxpy problem (issue: coupled systems)."""

import numpy as np
import pytest

from cvxid import CvxidError, Problem, Regression


def equations(seed):
    rng = np.random.default_rng(seed)
    n = 400
    u1, v1, u2, v2 = rng.standard_normal((4, n))
    # the same physical coefficient (0.7) enters both equations, with opposite signs
    y1 = 0.7 * u1 + 2.0 * v1 + 0.5 * rng.standard_normal(n)
    y2 = -0.7 * u2 + 1.0 * v2 + 0.5 * rng.standard_normal(n)
    first = Regression(np.c_[u1, v1], y1, ("u", "v"), ("library",) * 2, np.ones(2))
    second = Regression(np.c_[u2, v2], y2, ("u", "v"), ("library",) * 2, np.ones(2))
    return Regression.block({"a": first, "b": second})


def test_block_regression_names_and_zeros():
    joint = equations(0)
    assert joint.names == ("a:u", "a:v", "b:u", "b:v")
    assert np.all(joint.P[:400, 2:] == 0) and np.all(joint.P[400:, :2] == 0)


def test_tie_holds_exactly_and_pools_the_information():
    tied_errors, first_errors, second_errors = [], [], []
    for seed in range(100):
        joint = equations(seed)
        tied = Problem.from_regression(joint, ties=[("a:u", "b:u", -1.0)])
        both = tied.refit(np.ones(4, bool)).coefficients
        assert both[0] == pytest.approx(-both[2], rel=1e-7)
        free = Problem.from_regression(joint).refit(np.ones(4, bool)).coefficients
        tied_errors.append(both[0] - 0.7)
        first_errors.append(free[0] - 0.7)
        second_errors.append(-free[2] - 0.7)
    rms = [float(np.sqrt(np.mean(np.square(e)))) for e in (tied_errors, first_errors, second_errors)]
    assert rms[0] < 0.95 * min(rms[1:])  # the tie pools both equations' information
    lasso = tied.solve(1e-4).coefficients
    assert lasso[0] == pytest.approx(-lasso[2], rel=1e-7)
    assert "c[a:u] = -1 c[b:u]" in str(tied)


def test_bad_ties_are_named():
    with pytest.raises(CvxidError, match="both must be distinct columns"):
        Problem.from_regression(equations(0), ties=[("a:u", "a:u", 1.0)])
    with pytest.raises(CvxidError, match="both must be distinct columns"):
        Problem.from_regression(equations(0), ties=[("a:u", "c:u", 1.0)])


def test_ties_eliminated_give_the_cvxpy_solution_with_chains_and_signs(monkeypatch):
    """The tied refit by elimination (scipy's bounded least squares on merged columns)
    equals the cvxpy problem's solution: chains of ties, a negative factor, signs."""
    import cvxid.identify.problem as problem_module

    ties = [("a", "b", 2.0), ("b", "c", -0.5), ("d", "e", 3.0)]
    names = list("abcdef")
    for seed in range(20):
        rng = np.random.default_rng(seed)
        P = rng.standard_normal((300, 6)) * np.array([1.0, 10.0, 0.1, 2.0, 1.0, 5.0])
        y = P @ rng.standard_normal(6) + 0.1 * rng.standard_normal(300)
        problem = Problem.from_arrays(P, y, names, nonnegative=("c", "d"), ties=ties)
        eliminated = problem.refit(np.ones(6, bool)).coefficients
        with monkeypatch.context() as m:
            m.setattr(problem_module, "_tied_bounded_least_squares", lambda *a: None)
            by_cvxpy = problem.refit(np.ones(6, bool)).coefficients
        np.testing.assert_allclose(eliminated, by_cvxpy, rtol=1e-5, atol=1e-7 * np.abs(by_cvxpy).max())
        a, b, c, d, e, _ = eliminated
        assert a == pytest.approx(2 * b, rel=1e-12) and b == pytest.approx(-0.5 * c, rel=1e-12)
        assert d == pytest.approx(3 * e, rel=1e-12) and c >= 0 and d >= 0


def test_a_chain_of_ties_holds_whatever_the_order_it_is_written_in():
    """A tie keeps both of its columns: along a chain b = 2 c, a = 3 b with only a on the
    support, all three are refitted (the order of the ties does not matter)."""
    rng = np.random.default_rng(5)
    P = rng.standard_normal((200, 3))
    y = P @ np.array([6.0, 2.0, 1.0]) + 0.01 * rng.standard_normal(200)
    for ties in ([("b", "c", 2.0), ("a", "b", 3.0)], [("a", "b", 3.0), ("b", "c", 2.0)]):
        problem = Problem.from_arrays(P, y, list("abc"), ties=ties)
        a, b, c = problem.refit(np.array([True, False, False])).coefficients
        assert a == pytest.approx(3 * b, rel=1e-10) and b == pytest.approx(2 * c, rel=1e-10)
        assert c == pytest.approx(1.0, rel=0.01)


def test_a_block_regression_knows_each_equations_rows_through_column_subsets():
    """Regression.parts: the stacked equations' row counts, kept by a subset of columns
    (what stability selection and the acceptance test halve on the same stretches of
    time); one equation's regression has none."""
    joint = equations(0)
    assert joint.parts == (400, 400) and joint.subset(["b:v", "a:u"]).parts == (400, 400)
    assert equations(0).subset(["a:u"]).shape == (800, 1)
    single = Regression(np.ones((5, 1)), np.ones(5), ("u",), ("library",), np.ones(1))
    assert single.parts == ()


def test_a_candidate_tied_to_a_kept_term_does_not_hold_the_lambda_grid_open():
    """A seventh outside check: ``x^3`` (a candidate) tied to ``x`` (kept, unpenalised)
    stays wherever ``x`` is, so the largest lambda still 'kept a candidate': the grid was
    extended three times (lambda 2.3e8) and the run warned that the selection was not
    settled.  The tied term is held; the free candidate (truth 0) leaves, nothing warns."""
    import warnings

    from cvxid.identify.path import select

    rng = np.random.default_rng(0)
    P = rng.standard_normal((400, 3))
    truth = np.array([6.0, 0.0, 2.0])
    p = P @ truth + 0.01 * rng.standard_normal(400)
    Pt = rng.standard_normal((200, 3))
    pt = Pt @ truth
    problem = Problem.from_arrays(P, p, ["x", "x^2", "x^3"], weights=[0.0, 1.0, 1.0], ties=[("x^3", "x", 1 / 3)])
    np.testing.assert_array_equal(problem.held_by_ties, [False, False, True])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        path, best = select(problem, np.logspace(-4, 1, 20), lambda c: Pt @ c - pt, rule="1se")
    assert not [w for w in caught if "not settled" in str(w.message)]
    assert path.lambdas.max() == 10.0 and path.open_edge("1se") is None
    np.testing.assert_allclose(best.coefficients[[0, 2]], [6.0, 2.0], rtol=1e-3)
    assert best.coefficients[1] == 0.0
