r"""A delay of the input: the system receives :math:`u(t - \tau_u)`.

.. math::

    m\,\ddot x + g(x, \dot x) = u(t - \tau_u) + b\, x^{(q)}(t - \tau)

A drive's amplifier, a network or a sample-and-hold makes the input act late; a model
without that lag fits its phase with wrong damping and stiffness.  Unlike the fed-back
delay, :math:`\tau_u` touches only the right-hand side: for a fixed :math:`\tau_u` the
regression target is the transform of the shifted input (:meth:`Experiment.input
<cvxid.data.experiment.Experiment.input>`), so the equation error is profiled over
:math:`\tau_u` like the fed-back delay (:func:`cvxid.identify.profile.profile_input_delay`)
and the output-error polish fits it with the other parameters.  To first order
:math:`u(t-\tau_u) \approx u(t) - \tau_u\,\dot u(t)`: the diagnosis scores a missing input
delay by the column of :math:`\dot u` (:class:`~cvxid.model.terms.InputRate`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cvxid.errors import CvxidError
from cvxid.metrics import band_edge

QUARTER_PERIOD = 0.25
"""The default largest input delay, in periods of the output's band edge: a lag of a
quarter period there turns a force into a damping of the opposite sign, a different
system rather than a missing effect."""


@dataclass(frozen=True)
class InputDelay:
    """The input's delay: its current ``value`` and the bounds of its estimate
    (``tau_min == tau_max``: known; ``tau_max = inf``: from the data, :meth:`resolved`)."""

    value: float = 0.0
    tau_min: float = 0.0
    tau_max: float = 0.0

    def __post_init__(self):
        for name in ("value", "tau_min", "tau_max"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating)) and v >= 0 and (np.isfinite(v) or name == "tau_max")):
                raise CvxidError(f"[model.input_delay] {name} must be a finite number >= 0 (seconds), got {v!r}")
        if not self.tau_min <= self.value <= self.tau_max:
            raise CvxidError(f"[model.input_delay] needs tau_min <= value <= tau_max, got {self.tau_min:g}, "
                             f"{self.value:g} and {self.tau_max:g}")

    @classmethod
    def known(cls, value: float) -> "InputDelay":
        return cls(float(value), float(value), float(value))

    @property
    def free(self) -> bool:
        """Whether the value is estimated (its bounds differ)."""
        return self.tau_max > self.tau_min

    def resolved(self, bound: float) -> "InputDelay":
        """Finite bounds: an unbounded ``tau_max`` becomes ``bound`` (:func:`record_bound`)."""
        if np.isfinite(self.tau_max):
            return self
        if self.tau_min >= bound:
            raise CvxidError(f"[model.input_delay] tau_min = {self.tau_min:g} s is at or above the default tau_max, "
                             f"{bound:.4g} s (a quarter period of the output's band edge): give tau_max as well")
        return replace(self, tau_max=bound)

    def at(self, value: float) -> "InputDelay":
        """The same bounds at another value (clipped into them)."""
        return replace(self, value=float(np.clip(value, self.tau_min, self.tau_max)))

    def as_dict(self) -> dict:
        return {"value": self.value, "tau_min": self.tau_min, "tau_max": self.tau_max}

    @classmethod
    def from_dict(cls, data: dict) -> "InputDelay":
        return cls(float(data["value"]), float(data["tau_min"]), float(data["tau_max"]))


def record_bound(outputs, dt: float) -> float:
    """:func:`default_bound` of the fastest of ``outputs`` (sampled every ``dt``; NaN gaps
    ignored)."""
    edge = max(band_edge(y[np.isfinite(y)], dt) for y in (np.asarray(o, float) for o in outputs))
    return default_bound(edge)


def default_bound(band_edge: float) -> float:
    r""":math:`\tau_{u,\max} = \tfrac14\, 2\pi/\omega_{95}` (:data:`QUARTER_PERIOD` of the
    output's band edge :math:`\omega_{95}`, rad/s)."""
    if not band_edge > 0:
        raise CvxidError("the input delay's bound needs an output with a band (a constant output has none); "
                         "give [model.input_delay] tau_max")
    return QUARTER_PERIOD * 2 * np.pi / band_edge
