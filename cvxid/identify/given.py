r"""Values the spec gives, checked against the record.

A spec may give a value instead of estimating it: an equation's inertia (``inertia =
false`` with its ``mass``), the fed-back signal's gain (``[model.delay] gain``, a coupled
equation's ``delay_gain``), a tie between two coefficients (``[[model.tie]]``, ``left =
factor * right``).  The fit takes each as exact, and a wrong one moves the rest: a
thirteenth outside check gave a mass 10 % too high and got a delay of 0.367 s for 0.15 and
a damping 56 % low, with intervals that excluded the truth and no word (a tie that
contradicted the data did the same, and the one warning blamed the record's length).

After the run's final output-error polish :math:`\hat\theta` (residual :math:`r` on the
training record, Jacobian :math:`J` in its free parameters) each given value :math:`v` is
tested by the **score (Lagrange-multiplier) test** of freeing it (:mod:`cvxid.identify.score`):
with :math:`j_v = \partial r / \partial v` (the system with :math:`v` free, linearised at
:math:`\hat\theta`),

.. math::

    j_\perp = (I - J J^+)\, j_v, \qquad
    \mathrm{LM}_v = \frac{(j_\perp^T r)^2}{j_\perp^T j_\perp\,\hat\sigma^2}\,\frac{n_{\rm eff}}{n},
    \qquad \hat\sigma^2 = \frac{r^T r}{n - p},

:math:`\chi^2_1` when :math:`v` is right (:math:`n_{\rm eff}` the independent residuals,
:func:`~cvxid.identify.profile.effective_rows`): one batch of simulations for :math:`J`,
then one per value (:math:`j_v` by a forward difference), no fit.  A value whose statistic
passes :data:`LEVEL` (shared by the values checked: Bonferroni) and whose Gauss–Newton step
:math:`-j_\perp^T r / j_\perp^T j_\perp` reaches half of :data:`CHANGE` is freed and the model
polished again, its delay profiled as the run's own
(:func:`~cvxid.identify.output_error.polish`); the record **disagrees** with the value when
that fit moves it by more than :data:`CHANGE` and its training simulation error falls
beyond the profile's likelihood-ratio bound,

.. math::

    \mathrm{SSE}_{\rm free} \,\big(1 + \kappa\,\chi^2_{1,1-\alpha}/n_{\rm eff}\big) < \mathrm{SSE}_{\rm given},

(:math:`\kappa` the polish's input-noise inflation).  The given value stays (it is the
user's); the run says which values the record disagrees with, what each becomes when
estimated and where the delay moves (a missing effect can also make a right value look
wrong: where several disagree, the one whose estimate is plausible is the suspect).  A
given value the record cannot tell from others (a known gain 20 % high that the stiffness
and the delay absorb at the noise level) passes: the intervals then hold for the given
value only.  A Taylor-expanded delay's gain is not checked (the expansion needs it), nor a
known input delay; a delay pressed against a bound of its range is not free in :math:`J`
(:func:`~cvxid.identify.output_error.linearisation`), so a wrong value that holds it there
can pass (2 of 20 masses 10 % off on random held-out systems: ``examples/given_values.py``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Callable, Iterator

import numpy as np
from scipy.stats import chi2

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError
from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.identify.output_error import PolishResult, linearisation, polish, residual
from cvxid.identify.profile import effective_rows
from cvxid.identify.score import score_gains

LEVEL = 0.01
"""The level of the score test and of the refit's bound, shared by the values checked
(a warning, not a change of the estimate: a false alarm costs a reader's time)."""
CHANGE = 0.01
"""A given value disagrees only where its estimate differs from it by more than this share
of it: a long record tells a value from one 0.004 % away (the shipped flexible joint's
motor gain, its friction modelled as ``sign``, not the rig's ``tanh``), which moves
nothing the run reports.  The refit runs only where the score test's Gauss–Newton step
from the value reaches half of it (a first-order step into a valley can fall short)."""


@dataclass(frozen=True)
class GivenCheck:
    """One given value, tested at the final polish; when the score test flagged it, the
    polish with it free (``estimate`` its value there, ``tau`` the delay, ``rms`` the
    training simulation RMS against ``rms_given``)."""

    name: str  # the parameter ("m", "gain", a tie's left column; "label:column" in a coupled system)
    kind: str  # "mass", "gain" or "tie"
    what: str  # said to a reader: "the mass m", "the tie x^3 = 0.2 x"
    given: float  # the value (a tie's factor)
    statistic: float  # the score statistic (chi-square, 1 degree of freedom)
    p: float
    disagrees: bool = False
    estimate: float | None = None
    interval: tuple[float, float] | None = None
    tau: float | None = None
    rms: float | None = None
    rms_given: float | None = None
    fix: str = ""  # how to estimate it instead

    @property
    def stated(self) -> str:
        """The value as the spec gives it: "the mass m = 1.1", "the tie x^3 = 0.2 x"."""
        return self.what if self.kind == "tie" else f"{self.what} = {self.given:.4g}"

    def sentence(self) -> str:
        """What the freed fit gave, for the run's warning."""
        interval = "" if self.interval is None or not np.all(np.isfinite(self.interval)) else \
            f" [{self.interval[0]:.4g}, {self.interval[1]:.4g}]"
        delay = "" if self.tau is None else f", the delay {self.tau:.4g} s"
        value = ": its factor estimated" if self.kind == "tie" else ": estimated"
        return (f"{self.stated}{value}, {self.estimate:.4g}{interval}{delay}, simulation RMS "
                f"{self.rms:.4g} against {self.rms_given:.4g} (score test p = {self.p:.1e}; {self.fix})")

    def as_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind, "what": self.what, "given": self.given,
                "statistic": self.statistic, "p": self.p, "disagrees": self.disagrees, "estimate": self.estimate,
                "interval": None if self.interval is None else list(self.interval), "tau": self.tau, "rms": self.rms,
                "rms_given": self.rms_given}


@dataclass(frozen=True)
class _Given:
    parameter: str  # its name among the freed fit's parameters
    kind: str
    what: str
    given: float
    value: float  # the parameter's value at the fit (a tie's left coefficient)
    at: Callable[[float], IdentifiedSystem]  # the system with the value free, set to its argument
    fix: str
    tie: tuple[str, str, float] | None = None

    @property
    def freed(self) -> IdentifiedSystem:
        return self.at(self.value)


def _freed(system: IdentifiedSystem, label: str, spec, column: str, sign: float = 1.0):
    """The function of a value giving ``system`` with ``label``'s equation read by
    ``spec`` and its coefficient ``column`` set to ``sign`` times the value."""
    model = system.models[label]
    return lambda value: replace(system, models={**system.models, label: IdentifiedModel(
        spec, {**model.coefficients, column: sign * value}, model.lam, dict(model.info), model.tau)})


def _untied(system: IdentifiedSystem, tie: tuple[str, str, float]):
    """The function of a value giving ``system`` without ``tie``, its left column set to the value."""
    untied = replace(system, ties=tuple(t for t in system.ties if t != tie))
    label, column = (next(iter(system.models)), tie[0]) if system.single is not None else tie[0].split(":", 1)
    return _freed(untied, label, system.models[label].spec, column)


def _given_values(system: IdentifiedSystem) -> Iterator[_Given]:
    """Each value ``system``'s specs give, with the system that estimates it."""
    several = system.single is None
    for label, model in system.models.items():
        spec = model.spec
        where, named = (f" of {label}", lambda column: f"{label}:{column}") if several else ("", lambda column: None)
        if not spec.inertia:
            yield _Given(named(spec.inertia_term.name) or "m", "mass", f"the mass{where} m", spec.mass, spec.mass,
                         _freed(system, label, replace(spec, inertia=True), spec.inertia_term.name),
                         "to estimate it: inertia = true" + (f" in {label}'s equation" if several else " in [model]"))
        delay = spec.delay
        if delay is not None and delay.gain is not None and delay.exact and delay.gain != 0:
            yield _Given(named("gain") or "gain", "gain", f"the feedback gain{where}", delay.gain, delay.gain,
                         _freed(system, label, replace(spec, delay=replace(delay, gain=None)), spec.delayed_term.name,
                                -1.0),
                         "to estimate it: leave out " + (f"{label}'s delay_gain" if several else "[model.delay] gain"))
    for tie in system.ties:
        left, right, factor = tie
        yield _Given(left if several else system.single.spec.parameter_name(left), "tie",
                     f"the tie {left} = {factor:g} {right}", factor, system.coefficients.get(left, 0.0),
                     _untied(system, tie), "to estimate both: remove that [[model.tie]]", tie)


STEP = 1e-5
"""The forward-difference step of a given value's column, relative to the value."""


def check_given(best: PolishResult, train: Experiment, schedule: dict | None = None) -> tuple[GivenCheck, ...]:
    """Every value ``best``'s specs give, tested on ``train`` (see the module docstring);
    empty when the specs give none.  ``schedule``: the run's polish settings, for the
    refit of a value the score test flags.  One batch of simulations for the fit's
    Jacobian, one simulation per value."""
    given = [item for item in _given_values(best.system) if item.value != 0]
    if not given or not np.isfinite(best.rms_after):
        return ()
    try:
        _, r, J = linearisation(best.system, [train], best.initial)
    except CvxidError:  # (a diverged simulation)
        return ()
    level, rows = LEVEL / len(given), effective_rows(r)
    sigma2 = float(r @ r) / max(r.size - J.shape[1], 1)
    checks = []
    for item in given:
        h = STEP * abs(item.value)
        try:
            column = (residual(item.at(item.value + h), [train], best.initial) - r) / h
        except CvxidError:
            continue
        (gain,), (step,) = score_gains(r, J, column[:, None])
        statistic = float(gain / sigma2 * rows / r.size)
        check = GivenCheck(item.parameter, item.kind, item.what, float(item.given), statistic,
                           float(chi2.sf(statistic, 1)), fix=item.fix)
        if check.p < level and abs(step) >= CHANGE / 2 * abs(item.value):
            check = _refitted(check, item, best, train, schedule, level)
        checks.append(check)
    return tuple(checks)


def _refitted(check: GivenCheck, item: _Given, best: PolishResult, train: Experiment, schedule: dict | None,
              level: float) -> GivenCheck:
    """``check`` with the polish of ``item.freed``: whether its simulation error falls
    beyond the likelihood-ratio bound, the value it estimates and the delay."""
    try:
        with warnings.catch_warnings():  # (the run's own warnings are about the model it reports)
            warnings.simplefilter("ignore")
            free = polish(item.freed, train, initial=best.initial, **(schedule or {}))
    except CvxidError:
        return check
    if not np.isfinite(free.rms_after):
        return check
    if item.tie is None:
        estimate, interval = free.parameters[check.name], free.interval(check.name)
    else:
        left, right, _ = item.tie
        coefficients = free.system.coefficients
        estimate, interval = coefficients[left] / coefficients[right] if coefficients.get(right) else np.nan, None
    bound = 1 + best.input_noise_inflation * chi2.ppf(1 - level, 1) / max(best.effective_rows, 1.0)
    disagrees = free.rms_after**2 * bound < best.rms_after**2 and abs(estimate - check.given) > CHANGE * abs(
        check.given)
    return replace(check, disagrees=bool(disagrees), estimate=float(estimate),
                   interval=None if interval is None else (float(interval[0]), float(interval[1])),
                   tau=free.parameters.get("tau"), rms=float(free.rms_after), rms_given=float(best.rms_after))


def checked_line(checks) -> str:
    """One line for the run's printout: each given value and its score test's p-value,
    those the record disagrees with marked ("" without checks)."""
    if not checks:
        return ""
    return "given values checked against the record (score test): " + "; ".join(
        f"{c.stated} p = {c.p:.2g}" + (" DISAGREES (the warning below)" if c.disagrees else "") for c in checks)
