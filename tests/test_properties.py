"""Property-based tests (hypothesis): the algebraic operation and the loaders, on inputs
nobody wrote by hand."""

from math import factorial

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cvxid.data.experiment import Experiment, load
from cvxid.errors import CvxidError
from cvxid.regression.algebraic import AlgebraicOrders, AlgebraicTransform

T = np.linspace(0.0, 1.5, 1501)
coefficient = st.floats(-10, 10, allow_nan=False, allow_infinity=False)
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@SETTINGS
@given(st.lists(coefficient, min_size=1, max_size=4), st.integers(0, 3), st.integers(1, 4))
def test_static_column_of_any_polynomial_is_its_closed_form(coefs, n, extra):
    # (-1)^n ∫^(m) t^n sum_a c_a t^a = (-1)^n sum_a c_a t^(n+a+m) (n+a)! / (n+a+m)!
    m = n + extra
    tr = AlgebraicTransform(T, AlgebraicOrders(n, m))
    z = sum(c * T**a for a, c in enumerate(coefs))
    exact = (-1) ** n * sum(c * T ** (n + a + m) * factorial(n + a) / factorial(n + a + m) for a, c in enumerate(coefs))
    scale = max(sum(abs(c) for c in coefs) * T[-1] ** (n + m + len(coefs)), 1e-12)
    np.testing.assert_allclose(tr.column(z, 0), exact, rtol=0, atol=1e-9 * scale)


@SETTINGS
@given(st.integers(1, 3), st.lists(coefficient, min_size=3, max_size=3), coefficient, coefficient)
def test_columns_are_linear_and_blind_to_initial_conditions(d, free, a, b):
    # the column of order d is linear in the signal, and any polynomial of degree < d
    # (the free part a solution may carry from its initial conditions) adds nothing
    tr = AlgebraicTransform(T, AlgebraicOrders.for_derivative_order(d))
    z1, z2 = np.sin(3 * T), np.exp(-T)
    lin = tr.column(a * z1 + b * z2, d)
    np.testing.assert_allclose(lin, a * tr.column(z1, d) + b * tr.column(z2, d), rtol=1e-9, atol=1e-12)
    homogeneous = sum(c * T**k for k, c in enumerate(free[:d]))
    scale = max(np.abs(tr.column(z1, d)).max(), 1e-300) * (1 + sum(abs(c) for c in free))
    assert np.abs(tr.column(z1 + homogeneous, d) - tr.column(z1, d)).max() < 1e-9 * scale


# (magnitudes below 1e-100 are refused with a message to rescale: tests/test_bad_input.py)
signal = st.lists(st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False).map(lambda v: v if abs(v) >= 1e-100 else 0.0),
                  min_size=20, max_size=60)


@SETTINGS
@given(signal, st.floats(1e-4, 1.0), st.sampled_from(["csv", "npz"]))
def test_loaders_round_trip_any_finite_record(tmp_path, values, dt, kind):
    x = np.array(values)
    t = np.arange(x.size) * dt
    f = np.cos(t) + x[::-1] * 1e-3
    path = tmp_path / f"record.{kind}"
    if kind == "csv":
        np.savetxt(path, np.column_stack([t, x, f]), delimiter=",", header="t,x,f", comments="", fmt="%.17g")
    else:
        np.savez(path, t=t, x=x, f=f)
    e = load(path, time="t", outputs={"x": "x"}, inputs={"f": "f"})
    np.testing.assert_array_equal(e.output("x"), x)
    np.testing.assert_array_equal(e.input("f"), f)


@SETTINGS
@given(signal, st.integers(0, 19), st.sampled_from([np.nan, np.inf, -np.inf]))
def test_a_bad_sample_anywhere_is_named(values, where, bad):
    x = np.array(values)
    x[where] = bad
    with pytest.raises(CvxidError) as info:
        Experiment(np.arange(x.size) * 0.01, {"x": x}, {"f": np.cos(np.arange(x.size))})
    assert "'output x'" in str(info.value) and f"the first at sample {where}" in str(info.value)
