r"""How well a simulated or predicted signal matches a measured one.

.. math::

    \text{fit} = 100\,\Bigl(1 - \frac{\|y - \hat y\|}{\|y - \bar y\|}\Bigr)\ \%

(the normalised root-mean-square fit of MATLAB's ``compare``: 100 % is a perfect match,
0 % is no better than the mean, and it is negative when worse).
"""

from __future__ import annotations

import numpy as np


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> float:
    """The normalised fit (%) of ``yhat`` to ``y`` over the samples ``yhat`` covers (a
    simulation that starts after the record's start is NaN before it)."""
    covered = ~np.isnan(yhat)
    y, yhat = np.asarray(y)[covered], np.asarray(yhat)[covered]
    return float(100 * (1 - np.linalg.norm(y - yhat) / np.linalg.norm(y - np.mean(y))))
