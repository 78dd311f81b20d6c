r"""Sensor faults a measured record can show: a clipped (saturated) sensor, a frozen
stretch, single outlier samples.

Each fault biases every coefficient silently: the algebraic integrals read a flat top as
the system's motion, and one glitch of fifty noise levels moves a whole window of rows.
:func:`sensor_faults` finds them in the measured coordinates (never in the inputs: a
piecewise-constant or saturated input is an input, not a fault); a run warns about each
one and, with ``faults = "gap"`` in its data table, marks the samples as gaps so that the
integrals restart around them (:func:`without_faults`).

The rules, each chosen to stay silent on quantised encoders and smooth noise-free
simulations:

- **clipped**: at least ``CLIP_MIN_FRACTION`` of the samples (and ``CLIP_MIN_SAMPLES``)
  sit exactly at the signal's maximum (or minimum), ``CLIP_RATIO`` times as many as at the
  nearest other value.  A quantised peak holds its top level about 2.4 times as long as
  the level below it (a parabola's time within :math:`q` of its top against the next
  :math:`q`), a saturated sensor hundreds of times.
- **frozen**: a run of identical consecutive samples at least ``FROZEN_MIN_SAMPLES``
  long and ``FROZEN_RATIO`` times the 99th percentile of the signal's run lengths (1 for
  a noisy signal, tens for a quantised one).
- **outlier**: a sample whose distance from the median of its five neighbours exceeds
  ``OUTLIER_LEVELS`` times the robust scale of those distances,

  .. math:: s(d) = \max\bigl(1.4826\,\mathrm{median}\,|d|,\; P_{99}(|d|)/3\bigr),
     \qquad d_k = y_k - \mathrm{median}(y_{k-2}, \dots, y_{k+2}),

  and whose distance from the cubic through its four neighbours,
  :math:`e_k = y_k - (-y_{k-2} + 4 y_{k-1} + 4 y_{k+1} - y_{k+2})/6 = \Delta^4 y_{k-2}/6`,
  exceeds ``OUTLIER_CUBIC_LEVELS`` times :math:`s(e)`, in runs of at most
  ``OUTLIER_MAX_RUN`` samples (a glitch, not a motion).
  The median alone takes a smooth turning point for a glitch where the noise is small
  (its median is the next sample, :math:`|\ddot y|\,\Delta t^2` away, while a monotone
  stretch's median is the sample itself); the cubic follows the turning point
  (:math:`e_k = O(\Delta t^4)`), and the median keeps a glitch's neighbours, which the
  cubic's :math:`e` shares, from being counted with it.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np
from scipy.ndimage import median_filter

from cvxid.errors import CvxidError, CvxidWarning
from cvxid.metrics import quantisation_step

CLIP_MIN_FRACTION = 0.002
CLIP_MIN_SAMPLES = 5
CLIP_RATIO = 10.0
FROZEN_MIN_SAMPLES = 50
FROZEN_RATIO = 10.0
OUTLIER_LEVELS = 20.0
OUTLIER_CUBIC_LEVELS = 10.0
OUTLIER_MAX_RUN = 3

FAULT_HANDLING = ("warn", "gap", "ignore")
"""What a loader does with a fault: warn about it (the default), mark its samples as gaps
(and warn that it did), or neither (a user who knows the record, e.g. a quantised encoder
at standstill)."""


@dataclass(frozen=True)
class SensorFault:
    """One fault of one measured signal.

    Attributes
    ----------
    signal : str
        The output's name.
    kind : str
        ``"clipped"``, ``"frozen"`` or ``"outlier"``.
    samples : numpy.ndarray
        Boolean mask of the faulty samples.
    detail : str
        What was seen, for the message.
    """

    signal: str
    kind: str
    samples: np.ndarray
    detail: str

    def message(self, experiment: str, handling: str = "warn") -> str:
        """The warning a run gives, with the fix."""
        seen = {"clipped": "is clipped", "frozen": "freezes", "outlier": "has outliers"}[self.kind]
        where = f"experiment '{experiment}': output '{self.signal}' {seen}: {self.detail}"
        if handling == "gap":
            return f"{where}; its {int(self.samples.sum())} samples are treated as gaps (faults = \"gap\")"
        if self.kind == "clipped":
            return (f"{where} (a saturated sensor biases every coefficient, and the peaks it lost are where a "
                    "stiffness nonlinearity shows: record with more range if you can; faults = \"gap\" in the "
                    "spec's data table drops the clipped samples, but the model then never sees the large "
                    "amplitudes: compare the test fits)")
        cause = {
            "frozen": "if the sensor froze, the record is wrong there; if the system stood still, ignore this",
            "outlier": "one glitch moves every row whose window holds it",
        }[self.kind]
        return (f"{where} ({cause}); set faults = \"gap\" in the spec's data table (or make those samples NaN "
                "and load with gaps = true) so that the integrals restart around them")


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Start and end (exclusive) of each run of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def _clipped(name: str, y: np.ndarray) -> list[SensorFault]:
    finite = y if not np.isnan(y).any() else y[np.isfinite(y)]
    faults = []
    extremes = (("maximum", finite.max()), ("minimum", finite.min()))
    for side, level in extremes[:1] if finite.max() == finite.min() else extremes:
        at = y == level
        count = int(at.sum())
        if count < max(CLIP_MIN_SAMPLES, CLIP_MIN_FRACTION * finite.size):
            continue
        others = finite[finite != level]
        if others.size == 0:
            continue
        nearest = others[np.argmin(np.abs(others - level))]
        if count < CLIP_RATIO * np.count_nonzero(finite == nearest):
            continue
        faults.append(SensorFault(
            name, "clipped", at,
            f"{count} samples ({100 * count / finite.size:.1f} %) sit at its {side} {level:.6g} in "
            f"{len(_runs(at))} stretches"))
    return faults


def _frozen(name: str, y: np.ndarray, skip: np.ndarray) -> list[SensorFault]:
    same = np.r_[False, y[1:] == y[:-1]]
    runs = [(a - 1, b) for a, b in _runs(same)]          # a run holds the sample before its first repeat
    if not runs:
        return []
    lengths = np.array([b - a for a, b in runs])
    typical = _percentile_with_ones(lengths, y.size - lengths.sum(), 99)
    mask = np.zeros(y.size, bool)
    longest = None
    for (a, b), length in zip(runs, lengths):
        if length >= max(FROZEN_MIN_SAMPLES, FROZEN_RATIO * typical) and not skip[a:b].any():
            mask[a:b] = True
            longest = max(longest or (0, 0, 0), (length, a, b))
    if longest is None:
        return []
    length, a, _ = longest
    return [SensorFault(
        name, "frozen", mask,
        f"{len(_runs(mask))} stretch(es) of one repeated value, the longest {length} samples from sample {a} "
        f"(99 % of its other runs of one value last at most {typical:.0f} samples)")]


def _percentile_with_ones(values: np.ndarray, ones: int, q: float) -> float:
    """``np.percentile`` of ``values`` (each above 1) and ``ones`` more values of 1,
    without the array of ones (a record's worth of samples)."""
    ordered = np.sort(values)
    if ordered.size == 0:
        return 1.0
    count = ordered.size + ones
    position = q / 100 * (count - 1)
    below = int(np.floor(position))
    at = lambda i: 1.0 if i < ones else float(ordered[min(i, count - 1) - ones])
    return at(below) + (position - below) * (at(below + 1) - at(below))


def _robust_scale(distance: np.ndarray) -> float:
    middle, high = np.percentile(distance, [50, 99])
    return max(1.4826 * middle, high / 3)


def _outliers(name: str, y: np.ndarray, skip: np.ndarray) -> list[SensorFault]:
    size, off_cubic = np.zeros(y.size), np.zeros(y.size)
    for a, b in _runs(np.isfinite(y)):                   # gaps (NaN) split the record
        piece = size[a:b]
        np.subtract(y[a:b], median_filter(y[a:b], size=5, mode="nearest"), out=piece)
        np.abs(piece, out=piece)
        if b - a >= 5:  # e_k is the fourth difference / 6 (a piece's first and last two samples keep 0)
            off_cubic[a + 2:b - 2] = np.abs(np.diff(y[a:b], 4)) / 6
    scale = _robust_scale(size)
    if scale == 0:
        return []
    far = (size > OUTLIER_LEVELS * scale) & ~skip
    far &= off_cubic > OUTLIER_CUBIC_LEVELS * _robust_scale(off_cubic)
    mask = np.zeros(y.size, bool)
    for a, b in _runs(far):
        if b - a <= OUTLIER_MAX_RUN:
            mask[a:b] = True
    if not mask.any():
        return []
    first = int(np.argmax(mask))
    return [SensorFault(
        name, "outlier", mask,
        f"{int(mask.sum())} isolated sample(s) far from their neighbours, the first at sample {first} "
        f"({size[first] / scale:.0f} times the typical distance)")]


def sensor_faults(experiment) -> list[SensorFault]:
    """The clipped, frozen and outlier samples of each measured output of ``experiment``
    (gaps, NaN samples, are left out of every rule)."""
    faults = []
    for name, y in experiment.outputs.items():
        if not np.isfinite(y).any():
            continue
        clipped = _clipped(name, y)
        skip = np.zeros(y.size, bool)
        for fault in clipped:
            skip |= fault.samples
        faults += clipped + _frozen(name, y, skip) + _outliers(name, y, skip)
    return faults


def without_faults(experiment, faults: list[SensorFault]):
    """``experiment`` with the faulty samples made NaN and loaded with gaps, so that the
    algebraic integrals restart around them."""
    outputs = dict(experiment.outputs)
    for fault in faults:
        y = outputs[fault.signal].copy()
        y[fault.samples] = np.nan
        outputs[fault.signal] = y
    return replace(experiment, outputs=outputs, gaps=True)


def checked(experiment, handling: str = "warn"):
    """``experiment`` after its sensor check: each fault a :class:`~cvxid.errors.CvxidWarning`
    (``"warn"``), its samples made gaps as well (``"gap"``), or nothing checked (``"ignore"``)."""
    if handling not in FAULT_HANDLING:
        raise CvxidError(f"faults must be one of {', '.join(FAULT_HANDLING)}, got {handling!r}")
    if handling == "ignore":
        return experiment
    faults = sensor_faults(experiment)
    for fault in faults:
        warnings.warn(fault.message(experiment.name, handling), CvxidWarning, stacklevel=3)
    for message in coarse_quantisation(experiment):
        warnings.warn(message, CvxidWarning, stacklevel=3)
    return without_faults(experiment, faults) if handling == "gap" and faults else experiment


COARSE_ROUNDING = 0.01
r"""Share of a measured signal's deviation above which its rounding error
:math:`q/\sqrt{12}` is worth a word.  Chosen on the tuning seeds of
``examples/rounded_records.py`` (random delayed oscillators, noise 0.002, 8 s, the true
terms and gain given): the delay's median error was 0.16–0.45 % unrounded, 0.47–1.3 % at
a share of 0.5 %, 0.96–1.3 % at 1 % and 3.3–4.3 % at 2 %; the test fits stay at the
noise's ceiling throughout."""


def coarse_quantisation(experiment) -> list[str]:
    """A message for each measured output rounded to steps whose error is more than
    :data:`COARSE_ROUNDING` of its deviation (an encoder's counts, an ADC's bits, a file
    written with few decimals): not a fault, but a noise the user may be able to remove."""
    messages = []
    for name, y in experiment.outputs.items():
        finite = y[np.isfinite(y)]
        q = quantisation_step(finite) if finite.size > 10 else 0.0
        spread = float(np.std(finite)) if finite.size else 0.0
        if q > 0 and spread > 0 and q / np.sqrt(12) > COARSE_ROUNDING * spread:
            levels = int(round((finite.max() - finite.min()) / q)) + 1
            messages.append(
                f"experiment '{experiment.name}': {name} is rounded to steps of {q:.3g} ({levels} levels over its "
                f"range); the rounding error q/sqrt(12) = {q / np.sqrt(12):.3g} is {100 * q / np.sqrt(12) / spread:.3g} "
                "% of its deviation and counts as noise: the delay and the terms in its velocity lose accuracy with "
                "it (a finer sensor or converter, or more decimals in the file, if the record has them)")
    return messages
