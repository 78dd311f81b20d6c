"""The score test (cvxid.identify.score): what one more parameter does to a least-squares fit."""

import numpy as np
import pytest

from cvxid.identify.score import score_gains


def test_the_gain_is_the_fall_of_the_squared_residual_when_the_column_is_fitted():
    # a linear least-squares problem: the first-order fall is the exact fall, its step the
    # new coefficient of the refit
    rng = np.random.default_rng(0)
    J, columns = rng.standard_normal((200, 3)), rng.standard_normal((200, 4))
    y = J @ [1.0, -2.0, 0.5] + 0.7 * columns[:, 2] + 0.1 * rng.standard_normal(200)
    theta = np.linalg.lstsq(J, y, rcond=None)[0]
    r = J @ theta - y  # residual = model - data, as the output-error fit's
    gains, steps = score_gains(r, J, columns)
    for c in range(4):
        both = np.column_stack([J, columns[:, c]])
        refit = np.linalg.lstsq(both, y, rcond=None)[0]
        fall = r @ r - np.sum((both @ refit - y) ** 2)
        assert gains[c] == pytest.approx(fall, rel=1e-9)
        assert steps[c] == pytest.approx(refit[-1], rel=1e-9)
    assert int(np.argmax(gains)) == 2 and steps[2] == pytest.approx(0.7, abs=0.05)


def test_a_column_the_fit_already_spans_gains_nothing():
    rng = np.random.default_rng(1)
    J = rng.standard_normal((100, 2))
    r = rng.standard_normal(100)
    gains, steps = score_gains(r, J, J @ [[2.0], [-1.0]])
    assert gains[0] == 0.0 and steps[0] == 0.0


def test_a_block_of_columns_gains_the_exact_fall_of_their_joint_refit():
    """block_score_gain: several columns joining at once (one effect added to several
    equations) gain the joint refit's fall, at the joint refit's coefficients; one column
    is score_gains."""
    from cvxid.identify.score import block_score_gain

    rng = np.random.default_rng(2)
    J, columns = rng.standard_normal((300, 3)), rng.standard_normal((300, 2))
    y = J @ [1.0, -2.0, 0.5] + columns @ [0.4, -0.3] + 0.1 * rng.standard_normal(300)
    r = J @ np.linalg.lstsq(J, y, rcond=None)[0] - y
    gain, steps = block_score_gain(r, J, columns)
    both = np.column_stack([J, columns])
    refit = np.linalg.lstsq(both, y, rcond=None)[0]
    assert gain == pytest.approx(r @ r - np.sum((both @ refit - y) ** 2), rel=1e-9)
    assert steps == pytest.approx(refit[-2:], rel=1e-9)
    one, step = block_score_gain(r, J, columns[:, :1])
    assert one == pytest.approx(score_gains(r, J, columns[:, :1])[0][0], rel=1e-12) and step.shape == (1,)
