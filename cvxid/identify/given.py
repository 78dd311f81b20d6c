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
:math:`\hat\theta`: it must re-simulate :math:`r` there) and :math:`\delta` its Gauss–Newton step,

.. math::

    j_\perp = (I - J J^+)\, j_v, \qquad \delta = -\frac{j_\perp^T r}{j_\perp^T j_\perp}, \qquad
    r_1 = r + j_\perp \delta, \qquad
    \mathrm{LM}_v = \frac{(j_\perp^T r)^2}{j_\perp^T j_\perp\,\hat\sigma_1^2}\,\frac{n_{\rm eff}(r_1)}{n},
    \qquad \hat\sigma_1^2 = \frac{r_1^T r_1}{n - p - 1},

:math:`\chi^2_1` when :math:`v` is right (then :math:`r_1 \approx r`; :math:`n_{\rm eff}` the
independent residuals, :func:`~cvxid.identify.profile.effective_rows`, of the residual the
freed fit would leave: a wrong value's smooth misfit in :math:`r` has few): one batch of
simulations for :math:`J`, two per value, no fit.  A value whose statistic passes
:data:`LEVEL` (shared by the values checked: Bonferroni) and whose step :math:`\delta`
reaches half of :data:`CHANGE` is freed and the model polished again, its delay profiled as
the run's own (:func:`~cvxid.identify.output_error.polish`); the record **disagrees** with the
value when that fit moves it by more than :data:`CHANGE` and its training simulation error
falls beyond the profile's likelihood-ratio bound on the freed fit's effective rows,

.. math::

    \mathrm{SSE}_{\rm free} \,\big(1 + \kappa\,\chi^2_{1,1-\alpha}/n_{\rm eff}\big) < \mathrm{SSE}_{\rm given},

(:math:`\kappa \ge 1` the freed polish's input-noise inflation), unless, where the run has
a test record, the test record contradicts it: the freed fit loses more on the test
record's free run than it gains on the training record, in the Gaussian log-likelihood of
the two records together (:math:`n` samples and sum of squares :math:`S` each),

.. math::

    n_{\rm test} \log\frac{S_{\rm test,free}}{S_{\rm test,given}}
    > n_{\rm train} \log\frac{S_{\rm train,given}}{S_{\rm train,free}}.

A model misspecified in a way no given value fixes (the paper's own data, made by forward
Euler steps) lets a freed right value soak up part of the misfit on the record it is
fitted to, not on another (the paper's gain 2, given right: freed, 2.79, the training
simulation RMS 0.010032 against 0.010036, p = 0.0002; the test record's 0.009988 against
0.009981).  A short test record weighs little (a review: a wrong gain, said from an 8 s
test record, went unsaid from a 2 s one, 0.01 % worse there, when the test record had to
confirm it beyond chance); a chance bound on the test record's effective rows instead
missed a right gain whose freed fit erred 24 % more there (a missing friction's smooth
misfit leaves few effective rows).  A freed fit that does not simulate the test record is
contradicted by it.  The counts are samples: a test record sampled faster than the training
one weighs more per second.  The given value stays
(it is the user's); the run says which values the record disagrees with, what each becomes when
estimated and where the delay moves (a missing effect can also make a right value look
wrong: where several disagree, the one whose estimate is plausible is the suspect).  A
given value the record cannot tell from others (a known gain 20 % high that the stiffness
and the delay absorb at the noise level) passes: the intervals then hold for the given
value only.  A Taylor-expanded delay's model is not checked (its columns carry the delay's
shares: its values are listed as not checked), nor a known input delay.  A delay at an end
of its range (pressed against it, not free in :math:`J`:
:func:`~cvxid.identify.output_error.linearisation`) hides a value that would pull it inside
from the score test: there every given value is refitted (:func:`check_given`), and where
the freed fit holds the delay at the same end, one the user set (the top, or a bottom above
0), the range is the likelier cause and the value is not faulted.
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
from cvxid.identify.score import score_refit

LEVEL = 0.01
"""The level of the score test and of the refit's bound, shared by the values checked
(a warning, not a change of the estimate: a false alarm costs a reader's time)."""
CHANGE = 0.01
"""A given value disagrees only where its estimate differs from it by more than this share
of it: a long record tells a value from one 0.004 % away (the shipped flexible joint's
motor gain, its friction modelled as ``sign``, not the rig's ``tanh``), which moves
nothing the run reports.  The refit runs only where the score test's Gauss–Newton step
from the value reaches half of it (a first-order step into a valley can fall short)."""
STEP = 1e-5
"""The forward-difference step of a given value's column, relative to the value."""
REPRODUCED = 1e-6
"""The freed model at the given value must re-simulate the fit's residual to this share of
its largest sample (else its column would measure a different model: not checked)."""


@dataclass(frozen=True)
class GivenCheck:
    """One given value and its test at the final polish: the score statistic, its p-value
    and the first-order change it asks for; where the refit ran, the polish with the value
    free (``estimate``: its value there, a tie's factor; ``tau`` the delay; ``rms`` the
    training simulation RMS against ``rms_given``; ``test_rms`` against ``test_rms_given``
    the test record's free runs, and ``contradicted`` where the test record contradicts the
    training record's disagreement: the freed fit loses more log-likelihood there than it
    gains on the training record, or does not simulate it; both only where the run has a
    test record and the training record disagrees).  ``reason`` says why a value was not
    checked (its statistic and p-value are then NaN)."""

    name: str  # the parameter as the polish names it ("m", "gain", a tie's left term; "label:column" when coupled)
    kind: str  # "mass", "gain" or "tie"
    what: str  # said to a reader: "the mass m", "y's feedback gain", "the tie x^3 = 0.2 x"
    given: float  # the value (a tie's factor)
    statistic: float = np.nan  # the score statistic (chi-square, 1 degree of freedom)
    p: float = np.nan
    change: float = np.nan  # the score test's Gauss-Newton step, a share of the value
    disagrees: bool = False
    estimate: float | None = None
    interval: tuple[float, float] | None = None  # (None for a tie's factor)
    tau: float | None = None
    rms: float | None = None
    rms_given: float | None = None
    test_rms: float | None = None  # the test record's free-run RMS of the freed fit (None: no test record, no
    #                                 disagreement on the training record, or the freed fit does not simulate it)
    test_rms_given: float | None = None  # and of the fit with the value given
    contradicted: bool = False  # the test record contradicts the training record's disagreement
    fix: str = ""  # how to estimate it instead
    reason: str = ""  # why it was not checked ("": checked)
    held: str | None = None  # "top" or "bottom": freed, the delay stays at that end of its range, as given

    @property
    def stated(self) -> str:
        """The value as the spec gives it: "the mass m = 1.1", "the tie x^3 = 0.2 x"."""
        return self.what if self.kind == "tie" else f"{self.what} = {self.given:.4g}"

    def sentence(self) -> str:
        """What the freed fit gave, for the run's warning."""
        interval = "" if self.interval is None or not np.all(np.isfinite(self.interval)) else \
            f" [{self.interval[0]:.4g}, {self.interval[1]:.4g}]"
        flipped = " (the opposite sign)" if self.estimate * self.given < 0 else ""
        delay = "" if self.tau is None else f", the delay {self.tau:.4g} s"
        value = ": its factor estimated" if self.kind == "tie" else ": estimated"
        test = "" if self.test_rms is None else \
            f", on the test record {self.test_rms:.4g} against {self.test_rms_given:.4g}"
        return (f"{self.stated}{value}, {self.estimate:.4g}{interval}{flipped}{delay}, simulation RMS "
                f"{self.rms:.4g} against {self.rms_given:.4g}{test} (score test p {_p(self.p)}; {self.fix})")

    def as_dict(self) -> dict:
        number = (lambda v: None if v is None or not np.isfinite(v) else float(v))
        return {"name": self.name, "kind": self.kind, "what": self.what, "given": self.given,
                "checked": not self.reason, "reason": self.reason or None, "statistic": number(self.statistic),
                "p": number(self.p), "change": number(self.change), "disagrees": self.disagrees,
                "estimate": number(self.estimate), "interval": None if self.interval is None else list(self.interval),
                "refitted": self.rms is not None, "tau": number(self.tau), "rms": number(self.rms),
                "rms_given": number(self.rms_given), "test_rms": number(self.test_rms),
                "test_rms_given": number(self.test_rms_given), "test_contradicts": bool(self.contradicted),
                "delay_held_at": self.held}


@dataclass(frozen=True)
class _Given:
    check: GivenCheck  # what is said of it before the test (name, kind, what, given, fix)
    value: float  # the parameter's value at the fit (a tie's left coefficient)
    at: Callable[[float], IdentifiedSystem] | None  # the system with the value free, set to its argument
    #                                                  (None: a Taylor delay's gain, which the expansion needs)
    ratio: tuple[str, str] | None = None  # a tie's (left, right) parameters: its factor after the refit

    @property
    def freed(self) -> IdentifiedSystem:
        return self.at(self.value)


def _freed(system: IdentifiedSystem, label: str, spec, column: str, sign: float = 1.0):
    """The function of a value giving ``system`` with ``label``'s equation read by
    ``spec`` and its coefficient ``column`` set to ``sign`` times the value."""
    model = system.models[label]
    return lambda value: replace(system, models={**system.models, label: IdentifiedModel(
        spec, {**model.coefficients, column: sign * value}, model.lam, dict(model.info), model.tau)})


def _given_values(system: IdentifiedSystem) -> Iterator[_Given]:
    """Each value ``system``'s specs give, with the system that estimates it (a tie as the
    fit keeps it: a chain of ties as a star)."""
    several = system.single is None

    def name(label: str, physical: str, column: str) -> str:  # (as the polish names its parameters)
        return f"{label}:{column}" if several else physical

    for label, model in system.models.items():
        spec = model.spec
        if not spec.inertia:
            yield _Given(GivenCheck(name(label, "m", spec.inertia_term.name), "mass",
                                    f"{label}'s mass" if several else "the mass m", float(spec.mass),
                                    fix="to estimate it: inertia = true" + (
                                        f" in {label}'s equation" if several else " in [model]")),
                         spec.mass, _freed(system, label, replace(spec, inertia=True), spec.inertia_term.name))
        delay = spec.delay
        if delay is None or delay.gain is None:
            continue
        for q, (gain, term, value, signal) in enumerate(zip(spec.gain_names, spec.delayed_terms, delay.gains,
                                                          delay.signals)):
            if not value:  # (a gain of 0: listed, nothing to move; None: estimated)
                continue
            alone = tuple(None if i == q else g for i, g in enumerate(delay.gains)) if delay.rate else None
            free = replace(spec, delay=replace(delay, gain=alone)) if delay.exact else None  # (the other still given)
            what = f"{label}'s feedback gain" if several else "the feedback gain"
            yield _Given(GivenCheck(name(label, gain, gain), "gain", what + (f" of {signal}" if delay.rate else ""),
                                    value, fix="to estimate it: leave out " + (
                                        f"{label}'s delay_gain" if several else "[model.delay] gain") + (
                                        " (both gains are then estimated)" if delay.rate else "")),
                         value, _freed(system, label, free, term.name, -1.0) if delay.exact else None)
    for tie in system.ties:
        left, right, factor = tie
        label, column = (next(iter(system.models)), left) if not several else left.split(":", 1)
        spec = system.models[label].spec
        parameter = left if several else spec.parameter_name(left)
        untied = replace(system, ties=tuple(t for t in system.ties if t != tie))
        yield _Given(GivenCheck(parameter, "tie", f"the tie {left} = {factor:g} {right}", float(factor),
                                fix="to estimate both: untie them ([[model.tie]])"),
                     system.coefficients.get(left, 0.0), _freed(untied, label, spec, column),
                     (parameter, right if several else spec.parameter_name(right)))


def check_given(best: PolishResult, train: Experiment, schedule: dict | None = None,
                test_residual: Callable[[IdentifiedSystem], np.ndarray | None] | None = None
                ) -> tuple[GivenCheck, ...]:
    r"""Every value ``best``'s specs give, tested on ``train`` (see the module docstring);
    empty when the specs give none.  ``schedule``: the run's polish settings, for the
    refits.  ``test_residual``: a system's free-run residual on the run's test record
    (None where it does not simulate), which may contradict a refit's disagreement
    (:func:`_test_record`); without it the training record decides alone.  One batch of
    simulations for the fit's Jacobian and two simulations per value; a full polish for
    each value refitted, and two free runs of the test record.

    The statistic's noise is the residual's that freeing the value would leave, to first
    order (:math:`r + j_\perp \delta`): a wrong value leaves a smooth misfit in :math:`r`,
    whose few effective rows would cap the statistic at their number (a mass 10 % high on
    a 4000-sample record: 15 effective rows, the statistic 12.5 for an 81 % fall).  Where
    the fit holds the delay at a bound of its range, the delay is not free in :math:`J` and
    a wrong value that holds it there scores low (two masses 10 % off on random held-out
    systems: p = 0.02, the delay at 0): where the delay sits at an end of its range
    (:meth:`~cvxid.model.delay.DelayedFeedback.end`) every value is refitted, the
    likelihood-ratio bound deciding alone."""
    given = list(_given_values(best.system))
    if not given or not np.isfinite(best.rms_after):
        return ()
    if any(m.spec.delay is not None and not m.spec.delay.exact for m in best.system.models.values()):
        return tuple(replace(item.check, reason="a Taylor delay's model, whose columns carry the delay's shares")
                     for item in given)
    try:
        names, r, J = linearisation(best.system, [train], best.initial)
    except CvxidError:  # (a diverged simulation)
        return tuple(replace(item.check, reason="the fit does not simulate") for item in given)
    delay = next(iter(best.system.specs.values())).delay
    at_end = "tau" in best.parameters and (  # (pressed against a bound, or within a sample or so of it)
        "tau" not in names or delay.end(best.parameters["tau"], train.dt) is not None)
    scored = [_scored(item, best, train, r, J) for item in given]
    level = LEVEL / max(sum(not check.reason for check in scored), 1)
    return tuple(_refitted(check, item, best, train, schedule, level, test_residual, r.size)
                 if not check.reason and (at_end or (check.p < level and abs(check.change) >= CHANGE / 2)) else check
                 for check, item in zip(scored, given))


def _scored(item: _Given, best: PolishResult, train: Experiment, r: np.ndarray, J: np.ndarray) -> GivenCheck:
    """``item``'s score test at the fit (residual ``r``, Jacobian ``J``)."""
    if item.value == 0:
        return replace(item.check, reason="its coefficient is 0 at the fit: nothing to move")
    h = STEP * abs(item.value)
    try:
        own = residual(item.freed, [train], best.initial)
        moved = residual(item.at(item.value + h), [train], best.initial)
    except CvxidError:
        return replace(item.check, reason="its freed model does not simulate")
    if np.max(np.abs(own - r)) > REPRODUCED * np.max(np.abs(r)):
        return replace(item.check, reason="its freed model does not reproduce the fit")
    gain, step, after = score_refit(r, J, (moved - r) / h)
    sigma2 = float(after @ after) / max(r.size - J.shape[1] - 1, 1)
    statistic = float(gain / sigma2 * effective_rows(after) / r.size)
    return replace(item.check, statistic=statistic, p=float(chi2.sf(statistic, 1)), change=float(step / item.value))


def _refitted(check: GivenCheck, item: _Given, best: PolishResult, train: Experiment, schedule: dict | None,
              level: float, test_residual: Callable[[IdentifiedSystem], np.ndarray | None] | None,
              samples: int) -> GivenCheck:
    """``check`` with the polish of ``item.freed`` (``samples``: the training residual's,
    every coordinate's): the value it estimates, the delay, and
    whether it disagrees: its training simulation error beyond the likelihood-ratio bound
    on the freed fit's effective rows, the value moved by more than :data:`CHANGE`, the
    delay not held at the same end of its range (:func:`_held`), and the test record (where
    ``test_residual`` gives one) not contradicting it (:func:`_test_record`).  (Asking the value to
    leave the freed fit's 95 % interval too, a re-review's idea against the right gain named
    beside a wrong mass, named no fewer gains on the report seeds and lost a wrong mass whose
    interval, widened along the gain's valley, held the given value.)"""
    try:
        with warnings.catch_warnings():  # (the run's own warnings are about the model it reports)
            warnings.simplefilter("ignore")
            free = polish(item.freed, train, initial=best.initial, **(schedule or {}))
    except CvxidError:
        return check
    if not np.isfinite(free.rms_after):
        return check
    if item.ratio is None:
        estimate, interval = free.parameters[check.name], free.interval(check.name)
    else:
        left, right = (free.parameters.get(n, np.nan) for n in item.ratio)
        estimate, interval = (left / right if right else np.nan), None
    chance = max(free.input_noise_inflation, 1.0) * chi2.ppf(1 - level, 1)
    moved = abs(estimate - check.given) > CHANGE * abs(check.given)
    held = _held(best, free, train)
    disagrees = bool(free.rms_after**2 * (1 + chance / max(free.effective_rows, 1.0)) < best.rms_after**2
                     and moved and held is None)
    gain = samples * np.log(best.rms_after**2 / free.rms_after**2)  # (the training record's log-likelihood gain)
    contradicted, test_rms, test_rms_given = _test_record(free.system, best.system, test_residual, gain) \
        if disagrees else (False, None, None)  # (only a disagreement is put to the test record)
    return replace(check, disagrees=disagrees and not contradicted,
                   estimate=float(estimate), interval=None if interval is None else tuple(map(float, interval)),
                   tau=free.parameters.get("tau"), rms=float(free.rms_after), rms_given=float(best.rms_after),
                   test_rms=test_rms, test_rms_given=test_rms_given, contradicted=contradicted, held=held)


def _test_record(free: IdentifiedSystem, given: IdentifiedSystem,
                 test_residual: Callable[[IdentifiedSystem], np.ndarray | None] | None,
                 gain: float) -> tuple[bool, float | None, float | None]:
    """Whether the test record contradicts freeing the value: the freed fit's free run
    there loses more Gaussian log-likelihood (samples times the log of the ratio of the
    sums of squares) than ``gain``, what it gains on the training record, or does not
    simulate it; and the two free runs' RMS (None where there is no test record or a free
    run does not simulate it)."""
    before = None if test_residual is None else test_residual(given)
    if before is None:
        return False, None, None
    after = test_residual(free)
    rms = float(np.sqrt(np.mean(before**2)))
    if after is None:
        return True, None, rms
    loss = after.size * np.log(float(after @ after) / float(before @ before))
    return bool(loss > gain), float(np.sqrt(np.mean(after**2))), rms


def _held(best: PolishResult, free: PolishResult, train: Experiment) -> str | None:
    """The end of the delay's search range where both ``best`` and the freed fit ``free``
    hold the delay, else None.  A wrong given value that holds the delay at an end lets it
    back inside when freed; where the freed fit stays at the same end, the range (a true
    delay outside it) is the likelier cause, and freeing a right value merely soaks up its
    misfit (a re-review: with ``tau_max`` 0.1 s for a delay of 0.15 the right gain was said
    to disagree, its interval holding it)."""
    delay = next(iter(best.system.specs.values())).delay
    if delay is None or "tau" not in best.parameters or "tau" not in free.parameters:
        return None
    end = delay.end(best.parameters["tau"], train.dt)
    if end == "bottom" and delay.tau_min == 0:  # (no delay lies below 0: the range cannot be the cause there)
        return None
    return end if end is not None and delay.end(free.parameters["tau"], train.dt) == end else None


def checked_line(checks: tuple[GivenCheck, ...]) -> str:
    """One line for the run's printout: each given value, its score test's p-value and the
    first-order change it asks for, those the record disagrees with marked, those not
    checked with why ("" without given values)."""
    if not checks:
        return ""
    said = []
    for c in checks:
        if c.reason:
            said.append(f"{c.stated} not checked ({c.reason})")
            continue
        text = f"{c.stated} p {_p(c.p)}" + (f", asks for {100 * c.change:+.3g} %" if c.p < LEVEL else "")
        if c.rms is not None:
            text += ("; refitted: DISAGREES (the warning below)" if c.disagrees else
                     f"; refitted: the delay stays at the {c.held} of its range (the range, not the value, is the "
                     "likelier cause)" if c.held else
                     f"; refitted: {c.estimate:.4g}, not a disagreement: the test record contradicts it ({_test(c)})"
                     if c.contradicted else f"; refitted: {c.estimate:.4g}, not a disagreement")
        said.append(text)
    return "given values (the score test of freeing each at the final fit, a refit where it flags one): " + \
        "; ".join(said)


def _test(check: GivenCheck) -> str:
    """The two test free runs, as said: "RMS 0.009988 freed against 0.009981 given (+0.068 %)"."""
    if check.test_rms is None:
        return "the freed fit does not simulate it"
    change = 100 * (check.test_rms / check.test_rms_given - 1)
    return f"RMS {check.test_rms:.4g} freed against {check.test_rms_given:.4g} given " + \
        (f"({change:+.2g} %)" if abs(change) < 10 else f"({change:+.0f} %)")


def _p(p: float) -> str:
    """A p-value as printed: "= 0.42", "< 1e-16" (below what double precision holds)."""
    return "< 1e-16" if p < 1e-16 else f"= {p:.2g}"
