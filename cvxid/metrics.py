r"""How well a simulated or predicted signal matches a measured one.

.. math::

    \text{fit} = 100\,\Bigl(1 - \frac{\|y - \hat y\|}{\|y - \bar y\|}\Bigr)\ \%

(the normalised root-mean-square fit of MATLAB's ``compare``: 100 % is a perfect match,
0 % is no better than the mean, and it is negative when worse).  Measurement noise caps
it below 100 % even for the true model: :func:`noise_ceiling_percent`.
"""

from __future__ import annotations

import numpy as np


def noise_level(y: np.ndarray) -> float:
    """Standard deviation of white measurement noise, from the median absolute third
    difference (smooth signals contribute almost nothing to it at fine sampling)."""
    d3 = np.diff(np.asarray(y, float), 3)
    return float(np.median(np.abs(d3)) / 0.6745 / np.sqrt(20.0))


def noise_ceiling_percent(y: np.ndarray) -> float:
    r"""The fit (%) a perfect model reaches on ``y`` when ``y`` carries white measurement
    noise of the level :func:`noise_level` reads off it:
    :math:`100\,(1 - \hat\sigma / \mathrm{std}(y))`."""
    y = np.asarray(y, float)
    return float(100 * (1 - noise_level(y) / np.std(y)))


def relative_error_percent(estimate, truth):
    """``100 (estimate - truth) / |truth|``, NaN where the truth is 0 (no relative scale:
    the estimate itself is the error there)."""
    estimate, truth = np.asarray(estimate, float), np.asarray(truth, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(truth != 0, 100 * (estimate - truth) / np.abs(truth), np.nan)


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> float:
    """The normalised fit (%) of ``yhat`` to ``y`` over the samples ``yhat`` covers (a
    simulation that starts after the record's start is NaN before it)."""
    covered = ~np.isnan(yhat)
    y, yhat = np.asarray(y)[covered], np.asarray(yhat)[covered]
    return float(100 * (1 - np.linalg.norm(y - yhat) / np.linalg.norm(y - np.mean(y))))
