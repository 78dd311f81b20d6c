r"""How well a simulated or predicted signal matches a measured one.

.. math::

    \text{fit} = 100\,\Bigl(1 - \frac{\|y - \hat y\|}{\|y - \bar y\|}\Bigr)\ \%

(the normalised root-mean-square fit of MATLAB's ``compare``: 100 % is a perfect match,
0 % is no better than the mean, and it is negative when worse).  Measurement noise caps
it below 100 % even for the true model: :func:`noise_ceiling_percent`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.signal import welch
from scipy.stats import chi2


SEGMENT_SHARE = 0.5
"""Each Welch segment of the spectra below spans this share of the record (three
half-overlapped segments): their resolution, two bins per record length, is the same in
the record's own time whatever its sample rate.  (A fixed 4,096 samples resolved 0.24 Hz
at 1 kHz and 4.9 Hz at 20 kHz: an outside check's plant of 0.36 Hz, sampled at 20 kHz,
got a band edge of 9.8 Hz and windows 20 times too short, with intervals missing the
truth.)"""
MAX_SEGMENT = 1 << 20
"""The longest Welch segment (samples): longer records are averaged over more segments,
in the memory of one chunk (:data:`CHUNK_SEGMENTS`)."""
CHUNK_SEGMENTS = 256
"""Welch segments averaged a chunk of the record at a time (scipy holds every segment's
spectrum at once: 10^7 samples took about 0.3 GB)."""


def _welch(y: np.ndarray, fs: float, segment: int) -> tuple[np.ndarray, np.ndarray]:
    """Welch's estimate (Hann segments half overlapped, each detrended), the segments'
    periodograms averaged a chunk of :data:`CHUNK_SEGMENTS` at a time: the same segments
    and mean as one call on the whole record, in the memory of a chunk."""
    hop = segment - segment // 2  # (scipy's: noverlap = segment // 2)
    if segment < 2 or y.size <= CHUNK_SEGMENTS * hop + segment:
        return welch(y, fs=fs, nperseg=segment)
    step = CHUNK_SEGMENTS * hop  # chunk j holds the segments starting in [j step, (j + 1) step)
    total, count = 0.0, 0
    for a in range(0, y.size - segment + 1, step):
        piece = y[a:min(a + step + segment - hop, y.size)]
        f, pxx = welch(piece, fs=fs, nperseg=segment)
        segments = (piece.size - segment) // hop + 1
        total, count = total + segments * pxx, count + segments
    return f, total / count


def _spectrum(y: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray, float]:
    r"""Welch's power spectral density of ``y`` and its floor: the white noise's mean
    density, from the median of the upper half (robust to a signal there) divided by a
    white bin's median-to-mean ratio (:math:`\chi^2` with the bins' degrees of freedom:
    ln 2 for one segment)."""
    segment = int(min(y.size, MAX_SEGMENT, max(16, SEGMENT_SHARE * y.size)))
    f, pxx = _welch(y - np.mean(y), fs, segment)
    averaged = 2 * max(1, (y.size - segment) // (segment // 2) + 1)  # degrees of freedom of each bin
    return f, pxx, float(np.median(pxx[f.size // 2:]) / (chi2.median(averaged) / averaged))


SIGNAL_DOMINATES = 3.0
"""Ratio of the third-difference estimate to the spectral floor's above which the signal,
not the noise, makes the third difference (a record sampled at a few times its band)."""


def noise_level(y: np.ndarray) -> float:
    r"""Standard deviation of white measurement noise, from the median absolute third
    difference (smooth signals contribute almost nothing to it at fine sampling); where that
    exceeds ``SIGNAL_DOMINATES`` times the estimate from the spectrum's floor (its upper
    half taken as white, :func:`_spectrum`), from the floor (the Silverbox, 610 Hz: 4.8 mV by the
    third difference, 0.12 mV by the floor).

    A quantised record (:func:`quantisation_step` :math:`q`) has third differences that
    are multiples of :math:`q`, whose median is read within its bin (the grouped median:
    the plain one sits on the grid, a few % off at noise 0.01 and steps of 0.001); where
    the noise or the motion dithers the steps, that estimate holds the rounding error
    already.  One whose estimate falls below the rounding error :math:`q/\sqrt{12}` is a
    staircase: most of its third differences are 0 (its noise read 0: an outside check,
    steps of 0.01 on a motion of 0.33 RMS, got the shortest smoothing window, a velocity of
    spikes and a test fit of 74 % for 99.7 %); its noise is then
    :math:`\sqrt{q^2/12 + \sigma_{\rm floor}^2}`, the spectrum's floor seeing part of the
    noise hidden under a step.  Measured on records rounded to 0.1 to 30 % of their RMS
    with noise under and over a step: within -5 … +25 % of the true error's deviation (the
    rounding added in the dithered case too, as a stranger's review found, counted it
    twice: up to +52 %, and windows a step longer)."""
    y = np.asarray(y, float)
    q = quantisation_step(y)
    d3 = np.abs(np.diff(y, 3))
    moving = np.count_nonzero(d3)
    if q == 0 and MOVING_SHARE * d3.size <= moving < d3.size:  # four equal samples of a record that is not
        d3 = d3[d3 > 0]  # quantised: a clipped or frozen stretch, which shows no noise (a clipped third read 100 %)
    # (medians in place: a long record's copies are record-sized)
    median = _grouped_median(d3, q) if q > 0 else float(np.median(d3, overwrite_input=True))
    differences = median / 0.6745 / np.sqrt(20.0)
    del d3
    _, _, floor_density = _spectrum(y, 1.0)
    floor = float(np.sqrt(0.5 * floor_density))
    white = floor if differences > SIGNAL_DOMINATES * floor else differences
    rounding = q / np.sqrt(12.0)
    return float(np.hypot(rounding, floor)) if white < rounding else white


MOVING_SHARE = 0.1
"""The share of a record's third differences that must be nonzero for its exact zeros to
be read as clipped or frozen stretches and left out of :func:`noise_level` (a clipped
record keeps 40 %; an input held between random steps, 1 %: its zeros are the signal)."""


def _grouped_median(values: np.ndarray, q: float) -> float:
    """The median of non-negative ``values`` that are whole multiples of ``q``, each read
    as spread evenly over its bin (``k q`` stands for ``[(k - 1/2) q, (k + 1/2) q)``, and 0
    for ``[0, q/2)``): the grouped-data median."""
    levels = np.round(values / q)
    m = float(np.median(levels, overwrite_input=True))  # (reorders levels: the counts below do not mind)
    below, at = np.count_nonzero(levels < m), np.count_nonzero(levels == m)
    low, width = (0.0, 0.5) if m == 0 else (m - 0.5, 1.0)
    return q * (low + width * (0.5 * levels.size - below) / max(at, 1))


QUANTISATION_SAMPLES = 1 << 20
"""Samples a record's quantisation step is read from (a sensor's step is the same
throughout; the first 2^20 tell it)."""
QUANTISED_SHARE = 0.99
"""Share of the nonzero sample-to-sample changes that must be whole multiples of the
smallest for a record to count as quantised."""


def quantisation_step(y: np.ndarray) -> float:
    r"""The step :math:`q` a quantised record's values are rounded to (an encoder's count,
    an ADC's least bit, a file's last printed digit), else 0: the largest :math:`c/k`
    (:math:`k \le 10`, :math:`c` one of the smallest changes between consecutive samples
    that make up at least 1 % of the nonzero ones) of which :data:`QUANTISED_SHARE` of the
    nonzero changes are whole multiples (to 1 % of the step).  A few off-grid samples (an
    interpolated or repaired one) neither set the step nor hide it.  Rounding to :math:`q`
    adds an error of standard deviation :math:`q/\sqrt{12}` when the signal crosses several
    levels between samples, and a slower staircase when it does not."""
    d = np.abs(np.diff(np.asarray(y[:QUANTISATION_SAMPLES], float)))
    d = d[(d > 0) & np.isfinite(d)]
    if d.size < 10:
        return 0.0
    values, counts = np.unique(d, return_counts=True)
    frequent = values[counts >= 0.01 * d.size][:3]
    for c in frequent:
        for k in range(1, 11):
            steps = d / (c / k)
            if np.mean(np.abs(steps - np.round(steps)) <= 0.01) >= QUANTISED_SHARE:
                return float(c / k)
    return 0.0


def noise_ceiling_percent(y: np.ndarray, driven: float = 0.0) -> float:
    r"""The fit (%) a perfect model's free run reaches on ``y`` when ``y`` carries white
    measurement noise of the level :func:`noise_level` reads off it, and the simulation,
    driven by a measured input, carries the RMS ``driven`` of its response to that input's
    own noise: :math:`100\,(1 - \sqrt{\hat\sigma^2 + \sigma_u^2} / \mathrm{std}(y))`."""
    y = np.asarray(y, float)
    return float(100 * (1 - np.hypot(noise_level(y), driven) / np.std(y)))


def noise_multiple(fit: float | None, ceiling: float | None) -> float | None:
    r"""A free run's error in multiples of what the noise allows, from its fit and the
    noise's ceiling (both %, :func:`noise_ceiling_percent`):
    :math:`(100 - \text{fit}) / (100 - \text{ceiling})`; None when either is missing (a
    diverged simulation, no ceiling)."""
    if fit is None or ceiling is None:
        return None
    return (100.0 - fit) / max(100.0 - ceiling, 1e-9)


INPUT_NOISE_SHARE = 0.05
"""The largest white-noise level, as a share of an input's standard deviation, that
:func:`measurement_noise` takes as measurement noise (above it: broadband excitation, white
noise or a PRBS, whose samples cannot be told from noise)."""


def measurement_noise(u: np.ndarray) -> float:
    """The white measurement noise on a measured input ``u`` (:func:`noise_level`), or 0
    where it exceeds :data:`INPUT_NOISE_SHARE` of ``u``'s spread (broadband excitation)."""
    level = noise_level(u)
    return level if 0 < level <= INPUT_NOISE_SHARE * np.std(u) else 0.0


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


def band_period(outputs, dt: float, share: float = 0.95) -> float:
    r"""The period :math:`2\pi/\omega` of the highest :func:`band_edge` among ``outputs``
    (arrays sampled every ``dt``, their NaN gaps left out), at most the shortest record's
    length: the time scale the records show, in their own time unit."""
    finite = [y[np.isfinite(y)] for y in (np.asarray(o, float) for o in outputs)]
    edge = max(band_edge(y, dt, share) for y in finite)
    longest = min(y.size for y in finite) * dt
    return float(min(2 * np.pi / edge, longest)) if edge > 0 else float(longest)


class SpectralPeak(NamedTuple):
    """The highest peak of a record's power spectrum: its period and the share of the
    signal's variance (above the noise floor) within :data:`PEAK_WIDTH` of its frequency."""

    period: float
    share: float


PEAK_WIDTH = 0.25
"""The band around a spectral peak, as a share of its frequency either side, whose variance
:func:`spectral_peak` gives (a lightly damped resonance's peak, damping ratio up to about
10 %, lies within it)."""


def spectral_peak(y: np.ndarray, dt: float) -> SpectralPeak:
    """The highest peak of the power spectrum of ``y`` (sampled every ``dt``, its NaN gaps
    left out; the mean left out), located between its bins by the parabola through the
    logarithms of its three (a bin of a Welch segment of half the record is two cycles of
    the record wide: the peak's own bin alone placed a 3.25 Hz resonance 2 % off, three half
    periods 9 ms off), and the share of the variance above the noise floor within
    :data:`PEAK_WIDTH` of it: near 1 for a narrow-band response (a lightly damped structure
    driven through its resonance), small for a broad-band one."""
    y = np.asarray(y, float)
    f, pxx, floor = _spectrum(y[np.isfinite(y)], 1.0 / dt)
    if f.size < 3:
        return SpectralPeak(float(y.size * dt), 0.0)
    i = 1 + int(np.argmax(pxx[1:-1]))
    a, b, c = np.log(np.maximum(pxx[i - 1:i + 2], np.finfo(float).tiny))
    shift = 0.5 * (a - c) / (a - 2 * b + c) if a - 2 * b + c < 0 else 0.0
    peak = f[i] + shift * (f[1] - f[0])
    if not peak > 0:
        return SpectralPeak(float(y.size * dt), 0.0)
    signal = np.maximum(pxx - floor, 0.0)
    near = np.abs(f - peak) <= PEAK_WIDTH * peak
    return SpectralPeak(float(1.0 / peak), float(signal[near].sum() / signal.sum()) if signal.sum() > 0 else 0.0)


HARMONICS = 3.0
"""The band a missing force's error fills, in multiples of the output's band edge
(:func:`band_edge`): a nonlinear force's odd harmonics up to the third
(:func:`excess_in_band`)."""


def excess_in_band(measured: np.ndarray, simulated: np.ndarray, dt: float, white: float) -> float:
    r"""The share of a free run's error power beyond white noise of standard deviation
    ``white`` that lies within :data:`HARMONICS` times the measured output's band edge:
    a missing force errs where the motion is (a hidden friction or stiffness outside the
    catalogue left 86–100 % of it there on the 26 held-out report systems, 8 s, whose
    training free run missed by 1.1 times what white noise allows or more), a coloured noise
    mostly above it (a 50 Hz hum 0 % on 10 of them, a low-passed noise 1–3 %).  The excess is summed with
    its sign on each side of the edge (the noise's bins scatter about their mean and
    cancel), each side at least 0; 0 when there is none."""
    f, pxx, _ = _spectrum(np.asarray(measured, float) - np.asarray(simulated, float), 1.0 / dt)
    excess = (pxx - 2.0 * white**2 * dt) * (f[1] - f[0])
    inside = f <= HARMONICS * band_edge(measured, dt) / (2 * np.pi)
    low, high = max(float(excess[inside].sum()), 0.0), max(float(excess[~inside].sum()), 0.0)
    return low / (low + high) if low + high > 0 else 0.0


def band_edge(y: np.ndarray, dt: float, share: float = 0.95) -> float:
    """The angular frequency below which ``share`` of the variance of ``y`` lies, above the
    noise floor (the white noise's mean density, :func:`_spectrum`).  The floor is
    subtracted with its sign: above the signal's band the noise's bins scatter about their
    mean and cancel in the sum (clipped at 0, their upper halves added up to more than 5 % of
    a record whose noise is half its signal, and the edge ran to Nyquist; a floor read as
    the bins' median, below their mean, left them a positive sum on records of one Welch
    segment)."""
    f, pxx, floor = _spectrum(y, 1.0 / dt)
    cumulative = np.cumsum(pxx - floor)
    if cumulative[-1] <= 0:
        return float(2 * np.pi * f[-1])
    return float(2 * np.pi * f[np.argmax(cumulative >= share * cumulative[-1])])
