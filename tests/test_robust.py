"""Huber's loss against spikes in the measured signal."""

import numpy as np

from cvxid.data.experiment import Experiment
from cvxid.identify.loss import huber_refit, huber_weights
from cvxid.identify.problem import Problem
from cvxid.model.equation import ModelSpec
from cvxid.model.library import Library
from cvxid.model.terms import parse_term
from cvxid.regression.builder import RegressionBuilder
from cvxid.simulate import System, simulate


def test_huber_weights_leave_inliers_alone(rng):
    r = rng.standard_normal(1000)
    r[:5] = 50.0
    w = huber_weights(r)
    assert np.all(w[:5] < 0.05) and np.mean(w[5:] == 1.0) > 0.8


def test_huber_fit_resists_spikes_where_least_squares_does_not(rng):
    t = np.arange(10001) * 1e-3
    force = lambda s: 3 * np.sin(1.9 * s) + 2 * np.sin(4.7 * s + 1) + 1.5 * np.sin(8.3 * s + 2)
    x, _ = simulate(System((parse_term("x'"), parse_term("x")), np.array([0.4, 6.0]), 1.0), t, force, 0.3, 0.0)
    x = x + 0.001 * rng.standard_normal(t.size)
    spikes = rng.choice(x.size, 20, replace=False)
    x[spikes] += rng.choice([-1, 1], 20) * 0.5
    spec = ModelSpec(Library([parse_term("x'"), parse_term("x")]), nonnegative=("x''",))
    reg = RegressionBuilder(spec, Experiment(t, {"x": x}, {"f": force(t)}), "savgol", window=0.25).at(None)
    truth = np.array([1.0, 0.4, 6.0])
    ls = Problem.from_regression(reg).refit(np.ones(3, bool)).coefficients
    huber, _ = huber_refit(reg, np.ones(3, bool))
    ls_error = np.max(np.abs(ls / truth - 1))
    huber_error = np.max(np.abs(huber.coefficients / truth - 1))
    assert ls_error > 0.05 and huber_error < ls_error / 3  # measured: 0.079 and 0.011
