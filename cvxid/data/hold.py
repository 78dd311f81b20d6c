r"""Inputs held between samples (a zero-order hold), and how to tell them.

A controller's or a data-acquisition card's command is usually *held*: it changes at a
sample instant and keeps its level until the next, :math:`u(t) = u_k` for
:math:`t_k \le t < t_{k+1}`.  cvxid reads an input between its samples as a smooth
(band-limited) signal, a cubic spline through the samples, which puts a held level change
midway between the two samples around it: half a sample early.  To first order a hold is
that smooth signal half a sample late,

.. math::

    \frac{1 - e^{-s\,\Delta t}}{s\,\Delta t} = e^{-s\,\Delta t/2}\,
    \frac{\sinh(s\,\Delta t/2)}{s\,\Delta t/2} \approx e^{-s\,\Delta t/2}
    \qquad (|s|\,\Delta t \ll 1),

so an input declared held (``[data.*] hold``) is read :math:`\Delta t/2` later (straight
between its samples, :meth:`~cvxid.data.experiment.Experiment.input`), in the regression,
every simulation and the output-error polish alike (the simulations then read those
samples as any input's).  Read smooth, a held step
input moved a fed-back delay of 0.15 s by 5–10 % at 1 kHz with intervals that missed it (an
eighth outside check); a half-sample input delay gave covering intervals.

The samples alone cannot say whether a signal that jumps was held on the sample grid or
switched between two samples by a generator that does not share the sampling clock (then
the smooth reading is right on average), so cvxid does not decide: a record whose input
looks held (:func:`looks_held`) and that does not say is warned about.
"""

from __future__ import annotations

import numpy as np

from cvxid.metrics import noise_level, quantisation_step

JUMP_NOISE = 8.0
"""A sample-to-sample change is a jump when it exceeds this many noise levels (times
:math:`\\sqrt 2`, the noise of a difference) ..."""
JUMP_ISOLATION = 4.0
"""... and this many times each of its neighbours (a smooth signal's changes vary slowly) ..."""
JUMP_ROUNDING = 1.5
"""... and, in a record rounded to a step (:func:`~cvxid.metrics.quantisation_step`) below
:data:`ROUNDING` of its range, this many steps: a slow smooth input recorded at 8 bits
changes by one step at a time, level between, and is no held command."""
ROUNDING = 0.05
"""The largest rounding step, as a share of the record's range, read as rounding (a PRBS's
or a held step's own level change reads as a "step" as large as its range)."""
HELD_CHECKED = 2**20
"""Samples of a record's start that a load checks for a held input (a hold shows in any
stretch; a record of 10^7 samples is not read twice more for it)."""
LEVEL_NOISE = 2.0
"""An input looks held when, between its jumps, it stays within this many noise levels
(RMS) of each stretch's mean."""


def jumps(u: np.ndarray) -> np.ndarray:
    """The indices ``k`` of ``u``'s isolated jumps :math:`u_k \\to u_{k+1}`: changes above
    :data:`JUMP_NOISE` noise levels (of a difference) and :data:`JUMP_ISOLATION` times either
    neighbouring change."""
    v = np.asarray(u, float)
    d = np.abs(np.diff(v))
    neighbour = np.maximum(np.r_[0.0, d[:-1]], np.r_[d[1:], 0.0])
    step = quantisation_step(v)
    rounding = step if step < ROUNDING * np.ptp(v) else 0.0  # (a PRBS's one level change is no rounding)
    floor = max(JUMP_NOISE * np.sqrt(2.0) * _noise(v), JUMP_ROUNDING * rounding)
    return np.flatnonzero((d > floor) & (d > JUMP_ISOLATION * neighbour))


def _noise(v: np.ndarray) -> float:
    """The noise level of a signal that may be a noise-free staircase: the lesser of
    :func:`~cvxid.metrics.noise_level` (which reads a staircase's steps as its rounding) and
    the median absolute change's (0 for a held signal without noise)."""
    return min(noise_level(v), 1.4826 * float(np.median(np.abs(np.diff(v)))) / np.sqrt(2.0))


def looks_held(u: np.ndarray) -> bool:
    r"""Whether ``u`` is a held signal and noise: it jumps (:func:`jumps`), and between its
    jumps it stays level, within :data:`LEVEL_NOISE` noise levels (RMS) of each stretch's
    mean.  A held step or PRBS input is; a sampled smooth one (a multisine, a chirp,
    filtered noise) is not, nor a record with gaps (NaN samples: not judged)."""
    v = np.asarray(u, float)
    if v.size < 4 or not np.all(np.isfinite(v)):
        return False
    k = jumps(v)
    if k.size == 0:
        return False
    starts = np.r_[0, k + 1]
    levels = np.repeat(np.add.reduceat(v, starts) / np.diff(np.r_[starts, v.size]), np.diff(np.r_[starts, v.size]))
    return bool(np.sqrt(np.mean((v - levels) ** 2)) <= LEVEL_NOISE * _noise(v) + 1e-12 * np.max(np.abs(v)))  # (round-off)
