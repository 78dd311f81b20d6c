"""The algebraic operation against closed forms, and its removal of initial conditions."""

from math import factorial

import numpy as np
import pytest

from cvxid.errors import CvxidError
from cvxid.regression.algebraic import AlgebraicOrders, AlgebraicTransform

T = np.linspace(0.0, 2.0, 4001)


def test_iterated_integral_of_polynomial():
    # ∫^(j) t^i t^a = t^(i+a+j) (i+a)! / (i+a+j)!
    tr = AlgebraicTransform(T, AlgebraicOrders(2, 3))
    for a in (0, 1, 3):
        z = T**a
        for i, j in [(0, 1), (2, 3), (1, 4)]:
            exact = T ** (i + a + j) * factorial(i + a) / factorial(i + a + j)
            np.testing.assert_allclose(tr.integral(z, i, j), exact, rtol=0, atol=1e-9 * exact.max())


def test_iterated_integral_of_exponential():
    # ∫^(j) e^t = e^t - sum_{k<j} t^k / k!
    tr = AlgebraicTransform(T, AlgebraicOrders(2, 3))
    z = np.exp(T)
    for j in (1, 2, 4):
        exact = np.exp(T) - sum(T**k / factorial(k) for k in range(j))
        np.testing.assert_allclose(tr.integral(z, 0, j), exact, atol=1e-10)


def test_static_column_formula():
    # d = 0: (-1)^n ∫^(m) t^n z, for z = 1: (-1)^n t^(n+m) n! / (n+m)!
    orders = AlgebraicOrders(3, 4)
    col = AlgebraicTransform(T, orders).column(np.ones_like(T))
    exact = -(T**7) * factorial(3) / factorial(7)
    np.testing.assert_allclose(col, exact, atol=1e-10)


def test_derivative_column_matches_laplace_of_exponential():
    # z = e^{-t}: Z = 1/(s+1); s^d Z minus initial terms; check against a direct
    # evaluation of L^{-1}[s^{-m} d^n/ds^n (s^d Z(s))] by the same formula on z^(d).
    # For z = e^{-t}, z^(d) = (-1)^d e^{-t}; the column of order d equals the static column
    # of z^(d) because the initial terms are polynomials in s that n >= d derivatives kill.
    orders = AlgebraicOrders(3, 4)
    tr = AlgebraicTransform(T, orders)
    z = np.exp(-T)
    for d in (1, 2, 3):
        direct = tr.column(z, d)
        via_derivative = AlgebraicTransform(T, orders).column((-1) ** d * np.exp(-T), 0)
        np.testing.assert_allclose(direct, via_derivative, atol=1e-9)


@pytest.mark.parametrize("d", [1, 2, 3])
def test_initial_conditions_removed_exactly(d):
    # any polynomial of degree < d has a zero d-th derivative: its column must vanish
    orders = AlgebraicOrders.for_derivative_order(d)
    tr = AlgebraicTransform(T, orders)
    for degree in range(d):
        col = tr.column(1.0 + 0.5 * T**degree, d)
        scale = np.abs(tr.column(np.exp(T), d)).max()
        assert np.abs(col).max() < 1e-10 * scale


def test_homogeneous_solution_leaves_residual_unchanged():
    # m x'' + c x' + k x = f: adding a free response (any initial condition) must not
    # change the regression residual of the true coefficients
    m, c, k = 1.3, 0.4, 5.0
    lam = np.roots([m, c, k])
    sigma, omega = lam[0].real, abs(lam[0].imag)
    xh = np.exp(sigma * T) * (0.7 * np.cos(omega * T) - 1.1 * np.sin(omega * T))
    orders = AlgebraicOrders.for_derivative_order(2)
    tr = AlgebraicTransform(T, orders)
    resid = m * tr.column(xh, 2) + c * tr.column(xh, 1) + k * tr.column(xh, 0)
    scale = max(np.abs(k * tr.column(xh, 0)).max(), 1e-300)
    assert np.abs(resid).max() < 1e-8 * scale


def test_weights_are_the_binomial_expansion():
    orders = AlgebraicOrders(2, 3)
    # the paper's P2 column: 2∫(3) x - 4∫(2) t x + ∫ t^2 x
    assert sorted(orders.weights(2), key=lambda w: w[2]) == [(1.0, 2, 1), (-4.0, 1, 2), (2.0, 0, 3)]


def test_orders_default_and_checks():
    o = AlgebraicOrders.for_derivative_order(3)
    assert (o.n, o.m) == (3, 4)
    with pytest.raises(CvxidError, match="n >= 3"):
        AlgebraicOrders.for_derivative_order(3, n=2)
    with pytest.raises(CvxidError, match="m >= 3"):
        AlgebraicOrders.for_derivative_order(3, m=2)
