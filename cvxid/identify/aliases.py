r"""A fed-back delay's aliases in a narrow-band record.

A record whose response is nearly one sinusoid of period :math:`T` (a lightly damped
structure driven through its resonance, a machine tool's chatter) hardly tells the fed-back
signal from itself half a period later with the opposite sign, or a whole period later:

.. math::

    b\,x(t-\tau) \;\approx\; -b\,x(t-\tau-T/2) \;\approx\; b\,x(t-\tau-T).

Its simulation error then has narrow basins half a period apart, the gain's sign flipping
from one to the next.  The output-error profile's grid can step over the true basin (a
twelfth outside check: a delay of 0.72 s, 2.3 periods, reported as 0.561 with the gain's
sign flipped and an interval of 4 ms, though 0.72 fitted better), and a true delay just
past the search range leaves its alias inside it, as confident as the truth would be.
In such a record (``output_error.narrow_band``) the polish profiles the delay on a grid
finer than the peak's period and fits each of the profile's basins with the delay free
(``output_error._basin_fits``), and the run fits its estimate's aliases past the range
(:func:`alias_starts`, ``output_error.longer_delay``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from ..identified import IdentifiedModel, IdentifiedSystem

BEYOND = (1, 2, 3, 4)
"""Half periods past the estimate at which the run fits a longer delay, those past the
search range's top (up to two periods past the estimate: an outside check's chatter at
0.85 s, searched to 0.5 s, ended at its alias 0.38, three half periods short; a true delay
further past the top is not looked for)."""


@dataclass(frozen=True)
class LongerDelay:
    """A delay past the search range that simulates the training record better than the
    estimate inside it (beyond the profile's chance bound): the estimate is its alias."""

    tau: float
    gain: float | None  # the estimated feedback gain there (None: given)
    rms: float  # its simulation RMS error, on the records' part both fits simulate
    rms_estimate: float  # the estimate's, there
    period: float  # the response's peak period
    tau_max: float  # the search range's top

    def advice(self) -> str:
        gain = "" if self.gain is None else f" and the gain {self.gain:.4g}"
        return (f"a delay of {self.tau:.4g} s{gain}, past the search range (tau_max = {self.tau_max:g} s), simulates "
                f"the training record better than the estimate (RMS {self.rms:.4g} against {self.rms_estimate:.4g}, "
                f"beyond chance): the response is narrow-band (its peak period {self.period:.4g} s), delays half a "
                "period apart fit it almost alike (the gain's sign flipping), and the estimate is the alias inside "
                f"the range; raise [model.delay] tau_max above {self.tau + self.period / 4:.3g} s and run again")


def alias_starts(tau: float, period: float, low: float, high: float, gain_free: bool,
                 half_periods=BEYOND) -> list[tuple[float, int]]:
    """The delays ``tau + j period / 2`` (``j`` in ``half_periods``) within ``[low, high]``
    and the sign of the gain there relative to ``tau``'s: odd ``j`` flip it, and need an
    estimated gain (a given one cannot flip)."""
    return [(tau + j * period / 2, -1 if j % 2 else 1) for j in half_periods
            if (gain_free or j % 2 == 0) and low <= tau + j * period / 2 <= high]


def with_gain_sign(system: IdentifiedSystem, sign: int) -> IdentifiedSystem:
    """``system`` with each equation's estimated feedback gain times ``sign`` (the column of
    its delayed signal), every other coefficient kept."""
    models = {}
    for label, model in system.models.items():
        coefficients = dict(model.coefficients)
        for term in model.spec.delayed_terms if model.spec.delay is not None else ():
            if term.name in coefficients:
                coefficients[term.name] = sign * coefficients[term.name]
        models[label] = IdentifiedModel(model.spec, coefficients, model.lam, dict(model.info), model.tau)
    return replace(system, models=models)
