"""The cvxpy problem: agreement with least squares, sign constraints, statuses."""

import warnings

import cvxpy as cp
import numpy as np
import pytest

import cvxid.identify.problem as problem_module
from cvxid import CvxidError, CvxidWarning, Problem
from cvxid.identify.stlsq import stlsq


@pytest.fixture
def regressors(rng):
    n = 2000
    P = rng.standard_normal((n, 6)) * np.array([1e-3, 1.0, 1e4, 5.0, 1e2, 0.1])
    truth = np.array([2e3, -1.5, 0.0, 0.7, 0.0, 40.0])
    p = P @ truth + 0.01 * rng.standard_normal(n)
    return P, p, truth


def test_lambda_zero_matches_least_squares_in_physical_units(regressors):
    P, p, _ = regressors
    prob = Problem.from_arrays(P, p, list("abcdef"))
    fit = prob.solve(0.0)
    ls = np.linalg.lstsq(P, p, rcond=None)[0]
    np.testing.assert_allclose(fit.coefficients, ls, rtol=1e-6)
    assert fit.status == cp.OPTIMAL


def test_lasso_and_refit_recover_the_support(regressors):
    P, p, truth = regressors
    prob = Problem.from_arrays(P, p, list("abcdef"))
    fit = prob.solve(1e-3)
    np.testing.assert_array_equal(fit.support, truth != 0)
    refit = prob.refit(fit.support)
    np.testing.assert_allclose(refit.coefficients, truth, rtol=1e-3)


def test_zero_weight_is_never_dropped(regressors):
    P, p, _ = regressors
    w = np.ones(6)
    w[0] = 0.0
    fit = Problem.from_arrays(P, p, list("abcdef"), weights=w).solve(10.0)
    assert fit.support[0] and fit.support.sum() == 1


def test_sign_constraint_binds(regressors):
    P, p, _ = regressors
    prob = Problem.from_arrays(P, p, list("abcdef"), nonnegative=["b"])
    fit = prob.solve(0.0)
    assert fit.coefficients[1] == pytest.approx(0.0, abs=1e-7)
    assert np.all(prob.refit(np.ones(6, bool)).coefficients[1] >= 0)
    assert "c[b] >= 0" in str(prob)


def test_stlsq_thresholds_in_scaled_units(regressors):
    P, p, truth = regressors
    fit = stlsq(Problem.from_arrays(P, p, list("abcdef")), 0.05)
    np.testing.assert_array_equal(fit.support, truth != 0)


def test_bad_arguments_are_named(regressors):
    P, p, _ = regressors
    with pytest.raises(CvxidError, match="unknown solver 'ECOS'"):
        Problem.from_arrays(P, p, list("abcdef"), solver="ECOS")
    with pytest.raises(CvxidError, match="nonnegative names unknown column"):
        Problem.from_arrays(P, p, list("abcdef"), nonnegative=["z"])
    with pytest.raises(CvxidError, match="6 distinct strings"):
        Problem.from_arrays(P, p, list("abcdea"))
    with pytest.raises(CvxidError, match="finite"):
        Problem.from_arrays(np.where(P > 1e4, np.nan, P), p, list("abcdef"))
    with pytest.raises(CvxidError, match="lambda must be"):
        Problem.from_arrays(P, p, list("abcdef")).solve(-1)
    with pytest.raises(CvxidError, match="identically zero"):
        Problem.from_arrays(np.c_[P, np.zeros(len(p))], p, list("abcdefg"))


def test_a_solver_that_stops_early_hands_over_to_the_next_and_says_so(regressors, monkeypatch):
    P, p, _ = regressors
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CvxidWarning)
        prob = Problem.from_arrays(P, p, list("abcdef"), solver="OSQP")
    reference = Problem.from_arrays(P, p, list("abcdef")).solve(1e-4)
    monkeypatch.setitem(problem_module.SOLVER_SETTINGS, "OSQP", dict(max_iter=3, polishing=False))
    with pytest.warns(CvxidWarning, match=r"solver OSQP: it (stopped with status 'user_limit'|reported an inaccurate "
                                          r"solution) at lambda = 0.0001; CLARABEL answered instead"):
        fit = prob.solve(1e-4)
    assert fit.solver == "CLARABEL" and fit.status == "optimal"
    assert fit.coefficients == pytest.approx(reference.coefficients, rel=1e-6)


def test_only_inaccurate_answers_are_reported_with_a_warning_never_as_zeros(regressors, monkeypatch):
    P, p, _ = regressors
    prob = Problem.from_arrays(P, p, list("abcdef"))
    attempt = Problem._attempt

    def inaccurate(self, solver, settings):
        error = attempt(self, solver, settings)
        self.cvxpy._status = cp.OPTIMAL_INACCURATE
        return error

    monkeypatch.setattr(Problem, "_attempt", inaccurate)
    with pytest.warns(CvxidWarning, match=r"only an inaccurate solution at lambda = 0.0001 \(CLARABEL: it reported an "
                                          r"inaccurate solution; OSQP: .*\): CLARABEL's is reported"):
        fit = prob.solve(1e-4)
    assert fit.status == "optimal_inaccurate" and np.any(fit.coefficients != 0)


def test_osqp_is_offered_with_a_warning(regressors):
    P, p, _ = regressors
    with pytest.warns(CvxidWarning, match=r"OSQP \(a first-order solver\) is not accurate"):
        Problem.from_arrays(P, p, list("abcdef"), solver="osqp")
