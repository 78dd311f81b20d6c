r"""The windows of the algebraic operation: from the data, or the user's.

The windowed operation (:class:`~cvxid.regression.algebraic.WindowedTransform`) acts as a
low-pass filter: a window of :math:`W` seconds keeps frequencies up to about
:math:`\omega \approx 2\pi\,\kappa / W`.  Shorter windows let in more noise and amplify it
(the kernel of a derivative of order :math:`d` grows like :math:`W^{-d}`); longer ones
filter away the band where the dynamics (the inertia, the delay) show, which makes the
columns collinear, and the whole record (the paper's form) weighs its last rows most: on a
200 s record of a linear oscillator it loses the inertia.  The default matches the window
to the band the output actually occupies,

.. math::

    W = \kappa\, \frac{2\pi}{\omega_{95}},

where :math:`\omega_{95}` is the frequency below which 95 % of the output's variance lies
(Welch's estimate, noise floor removed).  :math:`\kappa` = :data:`PERIODS` was chosen on
twelve random delayed oscillators of the tuning range (equation-error delay and parameters
with the true terms, noise 0.001 and 0.01; :math:`\kappa` = 0.75–1 tied, 0.5 and 1.5 worse),
not yet end to end through ``cvxid bench --heldout``.  The window is kept
between :data:`MIN_SAMPLES` samples and a quarter of the longest gap-free stretch (after an
exact delay's history), and chosen from that stretch's output; a stretch too short to
hold one window gives no rows (:func:`holding`).  (A quarter of the shortest stretch let a
gap 1 s into a 4.8 s record cut the windows from 1.1 s to 0.15 s, and the delay fell
from 0.147 to 0.001 s for 0.15, its damping standing in: a seventh outside check.)

A Taylor delay keeps the whole record by default: its truncation error grows like
:math:`(\omega\tau)^{r+1}`, and the whole-record operation, whose late rows are windows as
long as the record, weighs the low frequencies where the expansion holds; on the paper's
own data the whole record finds its 7-term support and windows of 0.5–2 s add 2–10
spurious terms.  An exact delay has no truncation error and takes the windows.

In a spec: ``[fit] window = "auto"`` (the default), a number of seconds (sliding windows),
``"record"``, or ``{ restart = 0.05 }`` for restart windows
(:class:`~cvxid.regression.algebraic.RestartTransform`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from cvxid.errors import CvxidError, CvxidWarning
from cvxid.metrics import band_edge

PERIODS = 1.0
"""Window length in periods of the output's 95 % band edge."""
MIN_SAMPLES = 21
"""The fewest samples a window may hold (the quadrature needs a few per oscillation)."""
WINDOWS = ("auto", "record")
KINDS = ("sliding", "restart")


@dataclass(frozen=True)
class Windows:
    """Local windows of the algebraic operation: ``seconds`` long, ``"sliding"`` (one
    window per row, shifted along the record) or ``"restart"`` (consecutive windows, a row
    at every sample)."""

    seconds: float
    kind: str = "sliding"

    def as_dict(self) -> dict:
        return {"kind": self.kind, "seconds": self.seconds}

    def __str__(self) -> str:
        return f"{self.kind} windows of {self.seconds:.3g} s"


def history_seconds(model) -> float:
    """The seconds at a record's start that an exact delay reads as its measured history
    (``tau_max``; 0 for any other model)."""
    return model.delay.tau_max if (model.delay is not None and model.delay.exact) else 0.0


def longest(experiments):
    """The longest of ``experiments`` (the gap-free stretches of the records)."""
    return max(experiments, key=lambda e: e.duration)


def windows_for_test(asked, train_windows: Windows | None, models, test):
    """A test record's windows: the training record's (``train_windows``), unless they were
    chosen automatically (``asked`` is ``"auto"``) and no gap-free stretch of ``test``
    holds one after a delay's history of ``models`` (then ``"auto"``: its own)."""
    too_long = train_windows is not None and any(
        train_windows.seconds > longest(test.segments()).duration - history_seconds(m) for m in models)
    return "auto" if asked == "auto" and too_long else train_windows


def usable_seconds(model, records) -> float:
    """The seconds after the delay's history that every one of ``records`` (whole records,
    gaps and all) holds in its longest gap-free stretch."""
    return min(longest(r.segments()).duration for r in records) - history_seconds(model)


def fitting_every(windows: Windows, model, records) -> Windows:
    """``windows`` shortened, where needed, to a quarter of :func:`usable_seconds`: windows
    that every record holds (a delay candidate's, shared by the training and the test
    record, whose automatic windows come from the training record's longest stretch)."""
    usable = usable_seconds(model, records)
    return Windows(float(min(windows.seconds, max(usable / 4, MIN_SAMPLES * records[0].dt))), windows.kind)


def holding(experiments, windows: Windows | None, model) -> list:
    """The stretches long enough to hold one of ``windows`` after the delay's history,
    the others left out with a warning that says how much of the record they hold (all of
    them without windows)."""
    if windows is None:
        return list(experiments)
    start = history_seconds(model)
    fits = [e.n > 1 and e.duration - start >= windows.seconds * (1 - 1e-9) for e in experiments]
    kept = [e for e, fit in zip(experiments, fits) if fit]
    short = [e for e, fit in zip(experiments, fits) if not fit]
    if short and kept:  # (none holding one: the transform's own error names the window and the samples)
        share = 100 * sum(e.n for e in short) / sum(e.n for e in experiments)
        warnings.warn(
            f"{len(short)} record(s) or gap-free stretch(es) ({', '.join(e.name for e in short[:3])}"
            f"{', …' if len(short) > 3 else ''}"
            f"; {share:.2g} % of the samples) are shorter than one window of the algebraic operation ({windows}) "
            "after the delay's history and give no rows; a shorter [fit] window keeps them", CvxidWarning,
            stacklevel=3)
    return kept or list(experiments)


def resolve_window(window, model, experiments) -> Windows | None:
    """The windows (``None``: the whole record) for ``window`` = ``"auto"`` (chosen from
    the output of the longest of ``experiments``, the records' gap-free stretches, and at
    most a quarter of its seconds after the delay's history), ``"record"``, a number of seconds (sliding windows),
    ``{"restart": seconds}`` / ``{"sliding": seconds}`` or :class:`Windows`."""
    e = longest(experiments)
    usable, dt = e.duration - history_seconds(model), e.dt
    if window is None or window == "record":
        return None
    if window == "auto":
        if model.keep_initial_conditions or (model.delay is not None and not model.delay.exact):
            return None  # the paper's Taylor delay: see the module docstring
        seconds = PERIODS * 2 * np.pi / band_edge(e.output(model.coordinate), e.dt)
        return Windows(float(max(min(seconds, usable / 4), MIN_SAMPLES * dt)))
    if isinstance(window, str):
        raise CvxidError(f"[fit] window must be a number of seconds, 'auto' or 'record', got '{window}'")
    if isinstance(window, dict):
        if len(window) != 1 or next(iter(window)) not in KINDS:
            raise CvxidError(f"[fit] window as a table is {{ restart = seconds }} or {{ sliding = seconds }}, "
                             f"got {window}")
        ((kind, seconds),) = window.items()
        window = Windows(seconds, kind)
    if not isinstance(window, Windows):
        window = Windows(window)
    if model.keep_initial_conditions:
        raise CvxidError(
            "[fit] window: keep_initial_conditions = true is exact only from the record's start; "
            "use window = 'record' with it"
        )
    if isinstance(window.seconds, bool) or not isinstance(window.seconds, (int, float)) or not window.seconds > 0:
        raise CvxidError(f"[fit] window must be a positive number of seconds, got {window.seconds!r}")
    if not window.seconds >= MIN_SAMPLES * dt * (1 - 1e-9):  # (dt read off another record may differ in its last bit)
        raise CvxidError(f"[fit] window = {window.seconds:g} s holds fewer than {MIN_SAMPLES} samples "
                         f"(dt = {dt:g} s); lengthen it")
    if window.seconds > usable:
        where = "the usable record" if len(experiments) == 1 else "the longest usable gap-free stretch"
        raise CvxidError(f"[fit] window = {window.seconds:g} s is longer than {where} ({usable:g} s "
                         "after tau_max); shorten it or use window = 'record'")
    return Windows(float(window.seconds), window.kind)
