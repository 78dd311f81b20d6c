r"""How well a simulated or predicted signal matches a measured one.

.. math::

    \text{fit} = 100\,\Bigl(1 - \frac{\|y - \hat y\|}{\|y - \bar y\|}\Bigr)\ \%

(the normalised root-mean-square fit of MATLAB's ``compare``: 100 % is a perfect match,
0 % is no better than the mean, and it is negative when worse).  Measurement noise caps
it below 100 % even for the true model: :func:`noise_ceiling_percent`.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import welch
from scipy.stats import chi2


SEGMENT = 4096
"""Samples per Welch segment of the spectra below."""


def _spectrum(y: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Welch's power spectral density of ``y`` and its floor, the median of its upper half
    (taken as white noise)."""
    f, pxx = welch(y - np.mean(y), fs=fs, nperseg=min(y.size, SEGMENT))
    return f, pxx, float(np.median(pxx[f.size // 2:]))


SIGNAL_DOMINATES = 3.0
"""Ratio of the third-difference estimate to the spectral floor's above which the signal,
not the noise, makes the third difference (a record sampled at a few times its band)."""


def noise_level(y: np.ndarray) -> float:
    """Standard deviation of white measurement noise, from the median absolute third
    difference (smooth signals contribute almost nothing to it at fine sampling); where that
    exceeds ``SIGNAL_DOMINATES`` times the estimate from the spectrum's floor (the median of
    its upper half, taken as white), from the floor (the Silverbox, 610 Hz: 4.8 mV by the
    third difference, 0.12 mV by the floor)."""
    y = np.asarray(y, float)
    d3 = np.diff(y, 3)
    differences = float(np.median(np.abs(d3)) / 0.6745 / np.sqrt(20.0))
    _, _, floor_density = _spectrum(y, 1.0)
    segment = min(y.size, SEGMENT)
    averaged = 2 * max(1, (y.size - segment) // (segment // 2) + 1)  # degrees of freedom of each bin
    median_to_mean = chi2.median(averaged) / averaged  # a white bin's median is below its mean (ln 2 for one segment)
    floor = float(np.sqrt(0.5 * floor_density / median_to_mean))
    return floor if differences > SIGNAL_DOMINATES * floor else differences


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


def band_edge(y: np.ndarray, dt: float, share: float = 0.95) -> float:
    """The angular frequency below which ``share`` of the variance of ``y`` lies, above the
    noise floor (the median of the upper half of the spectrum, taken as white noise).  The
    floor is subtracted with its sign: above the signal's band the noise's bins scatter
    about the floor and cancel in the sum (clipped at 0, their upper halves added up to more
    than 5 % of a record whose noise is half its signal, and the edge ran to Nyquist)."""
    f, pxx, floor = _spectrum(y, 1.0 / dt)
    cumulative = np.cumsum(pxx - floor)
    if cumulative[-1] <= 0:
        return float(2 * np.pi * f[-1])
    return float(2 * np.pi * f[np.argmax(cumulative >= share * cumulative[-1])])
