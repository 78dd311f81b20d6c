r"""The measured signal as the delayed feedback's history.

A record that starts mid-motion was driven, before its first sample, by feedback nobody
recorded: assuming it (zero, or the first sample held) puts a jump of :math:`b\,x_0` into
the simulated feedback where :math:`t-\tau` crosses the record's start, and that error
biases the delay.  cvxid assumes nothing: with ``history = "measured"`` (the default) a
simulation — free run, output-error polish, comparison — starts at

.. math::

    t_s = t_0 + \tau_{\max},

the first time at which every admissible delay reads inside the record, and until
:math:`t_s + \tau` the delayed term reads the measured signal, smoothed (Savitzky–Golay,
window chosen from the noise) and interpolated by a cubic spline.  The regression does the
same: its rows start at :math:`t_0 + \tau_{\max}`
(:class:`~cvxid.regression.builder.RegressionBuilder`).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.signal import savgol_filter

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError
from cvxid.regression.velocity import savgol_window
from cvxid.simulate import Past

MIN_SIMULATED = 20
"""The fewest samples a simulation after the start may have."""


def start_index(experiment: Experiment, delay, history: str | None = None) -> int:
    """The first sample a simulation of ``experiment`` starts from: where :math:`t - \\tau_{\\max}`
    enters the record for a measured history (``history`` overrides the delay's own),
    else the record's first sample."""
    history = history or (delay.history if delay is not None else None)
    if delay is None or history != "measured":
        return 0
    t = experiment.time
    k = int(np.searchsorted(t, t[0] + delay.tau_max - 1e-9 * experiment.dt))
    if t.size - k < MIN_SIMULATED:
        raise CvxidError(
            f"experiment '{experiment.name}' ({experiment.duration:g} s) leaves fewer than {MIN_SIMULATED} samples "
            f"after tau_max = {delay.tau_max:g} s, where a simulation with the measured history starts; "
            "lower [model.delay] tau_max or use a longer record"
        )
    return k


SPLINE_MARGIN = 64
"""Samples of the smoothed record kept beyond the last one a past is read at (a cubic
spline's dependence on far samples decays by about 0.27 a sample)."""


def measured_past(experiment: Experiment, coordinate: str, orders: tuple[int, ...] = (0,),
                  until: int | None = None) -> Past:
    """The fed-back signals (their derivative ``orders``, 0: position, 1: velocity) and their
    slopes ``(len(orders), n)`` at any time inside ``experiment`` (up to sample ``until``,
    when given): the smoothed measurement, by a cubic spline."""
    y = experiment.output(coordinate)
    w = savgol_window(y)
    n = y.size if until is None else min(y.size, until + w + SPLINE_MARGIN)
    # (w < n: the window is shorter than a quarter of the record, and the stretch is w longer)
    spline = CubicSpline(experiment.time[:n], savgol_filter(y[:n], w, 3, mode="interp"))
    return lambda times: (np.array([spline(times, q) for q in orders]), np.array([spline(times, q + 1) for q in orders]))


def simulation_start(experiment: Experiment, delay, history: str | None = None) -> tuple[int, Past | None]:
    """Where a simulation of ``experiment`` starts (:func:`start_index`) and the fed-back
    signal before it (:func:`measured_past`; None when it starts at the record's start)."""
    k = start_index(experiment, delay, history)
    return k, (measured_past(experiment, delay.coordinate, delay.orders, until=k) if k else None)


def padded(values: np.ndarray, start: int) -> np.ndarray:
    """A simulation from sample ``start`` on the record's full length (NaN before it)."""
    return np.concatenate([np.full((start,) + values.shape[1:], np.nan), values])
