"""One contract per plug-in family: every member of the family keeps it.

The families are the selectors along a λ path, the velocity estimators, the delay
parameterisations and the losses.  A new member joins the family by being added to the
list its contract is parametrised over, and the contract tells whether it belongs.
"""

import numpy as np
import pytest

from cvxid import Path, Problem
from cvxid.app.run import run
from cvxid.identify.loss import huber_refit
from cvxid.identify.path import ESTIMATORS as SELECTORS
from cvxid.model.delay import METHODS as DELAY_METHODS
from cvxid.regression.regression import Regression
from cvxid.regression.velocity import ESTIMATORS as VELOCITY_ESTIMATORS
from cvxid.regression.velocity import estimate_velocity
from cvxid.spec.load import parse_problem

from .conftest import ROOT

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover
    import tomli as tomllib

LOSSES = ("squared", "huber")


@pytest.fixture(scope="module")
def sparse():
    """Noise-free rows of a sparse linear model: columns d, e are not in it; c >= 0."""
    rng = np.random.default_rng(7)
    P = rng.standard_normal((400, 5))
    truth = np.array([1.5, -2.0, 0.7, 0.0, 0.0])
    Pt = rng.standard_normal((200, 5))
    return P, P @ truth, Pt, Pt @ truth, truth


@pytest.mark.parametrize("selector", SELECTORS)
def test_selector_contract(selector, sparse):
    """One fit per λ, every fit within the sign constraints, and the fit the validation
    picks is the truth on noise-free data."""
    P, p, Pt, pt, truth = sparse
    problem = Problem.from_arrays(P, p, list("abcde"), nonnegative=["c"])
    lambdas = np.logspace(-6, 0, 12)
    path = Path.compute(problem, lambdas, validate=lambda c: Pt @ c - pt, estimator=selector)
    assert len(path.fits) == lambdas.size
    assert all(f.coefficients[2] >= -1e-12 for f in path.fits)
    np.testing.assert_allclose(path.best("min").coefficients, truth, atol=1e-7)


@pytest.mark.parametrize("method", VELOCITY_ESTIMATORS)
def test_velocity_estimator_contract(method):
    """The velocity of a noisy two-tone signal within 10 % RMS of the truth, away from the
    record's ends (measured: observer 8.5 %, the smoothers below 3 %)."""
    rng = np.random.default_rng(1)
    t = np.arange(0, 10, 1e-3)
    y = np.sin(2 * t) + 0.3 * np.sin(5 * t + 1) + 1e-3 * rng.standard_normal(t.size)
    v = 2 * np.cos(2 * t) + 1.5 * np.cos(5 * t + 1)
    inner = slice(1000, -1000)
    estimate = estimate_velocity(y, t, method)
    assert estimate.shape == y.shape
    assert np.sqrt(np.mean((estimate - v)[inner] ** 2)) < 0.10 * np.sqrt(np.mean(v[inner] ** 2))


SPEC = """
[truth]
mass = 1.0
coefficients = {{ "x'" = 0.5, "x" = 6.0 }}
delay = {{ signal = "x", gain = 1.5, tau = 0.06 }}
[model]
library = {{ terms = ["x", "x'"] }}
delay = {{ signal = "x", {delay} }}
names = {{ k = "x", c = "x'" }}
[data.train.simulate]
duration = 10.0
dt = 1e-3
input = [{{ kind = "sine", amplitude = 2.0, omega = 1.3 }}, {{ kind = "sine", amplitude = 1.0, omega = 3.1 }}]
[fit]
estimator = "lstsq"
"""
DELAYS = {"taylor": 'method = "taylor", taylor_order = 3, gain = 1.5', "exact": 'method = "exact", gain = 1.5, tau_max = 0.2'}


@pytest.mark.parametrize("method", DELAY_METHODS)
def test_delay_parameterisation_contract(method):
    """A delay parameterisation turns the regression's coefficients into tau and the
    physical parameters: on noise-free data of a slow delayed oscillator (omega tau < 0.3)
    each gives tau within 1 % and the stiffness within 0.5 %."""
    spec = parse_problem(tomllib.loads(SPEC.format(delay=DELAYS[method])), ROOT)
    physical = run(spec).model.physical
    assert physical["tau"] == pytest.approx(0.06, rel=0.01)
    assert physical["k"] == pytest.approx(6.0, rel=0.005)


@pytest.mark.parametrize("loss", LOSSES)
def test_loss_contract(loss, sparse):
    """Exact on clean rows; and no worse than the squared loss when 1 % of the rows are
    gross outliers."""
    P, p, _, _, truth = sparse
    names = tuple("abcde")
    support = np.array([True, True, True, False, False])

    def fitted(target):
        regression = Regression(P, target, names, ("library",) * 5, np.ones(5))
        if loss == "huber":
            return huber_refit(regression, support)[0].coefficients
        return Problem.from_regression(regression).refit(support).coefficients

    np.testing.assert_allclose(fitted(p), truth, atol=1e-9)
    spoiled = p.copy()
    spoiled[::100] += 50.0
    error = np.abs(fitted(spoiled) - truth).max()
    ordinary = np.zeros(5)  # ordinary least squares, by numpy, on the support
    ordinary[support] = np.linalg.lstsq(P[:, support], spoiled, rcond=None)[0]
    assert error <= np.abs(ordinary - truth).max() * (1 + 1e-9)
    if loss == "squared":
        np.testing.assert_allclose(fitted(spoiled), ordinary, atol=1e-9)
    else:
        assert error < 0.05 < np.abs(ordinary - truth).max()
