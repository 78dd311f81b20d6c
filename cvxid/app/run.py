r"""The main job: a problem spec in, an identified system and its figures out.

``run(spec)`` identifies a system of :math:`N \ge 1` equations (one ``[model]``, or
``[[model.equation]]`` tables with a shared delay and ties) the same way whatever
:math:`N`: load or simulate the experiments; transform them once
(:class:`~cvxid.regression.builder.SystemBuilder`); for an exact delay, profile it on the
whole library; (optionally) search the library order; sweep :math:`\lambda` and select on
the test experiment (with stability selection over halves of the record), or select by
simulation error (``stepwise_oe``); (optionally) bootstrap; for an exact delay, profile it
again on the selected support; (optionally) the Huber loss; (optionally) diagnose and add
the missing effects; (optionally) polish by output error and prune the selected terms the
simulation does not need.  It returns a :class:`~cvxid.app.result.RunResult`.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import replace
from pathlib import Path as FilePath

import numpy as np
import pandas as pd

from cvxid.app.result import RunResult
from cvxid.data.experiment import Experiment
from cvxid.data.hold import looks_held
from cvxid.diagnosis.acceptance import stop_reason
from cvxid.diagnosis.compare import compare_system, free_run_residual
from cvxid.diagnosis.ranking import diagnose
from cvxid.diagnosis.refine import refine, zeroed
from cvxid.diagnosis.simulation import refine_by_simulation
from cvxid.errors import CvxidError, CvxidWarning, EquationErrorDelayWarning
from cvxid.identify.bootstrap import BootstrapSettings, bootstrap, with_delays
from cvxid.identify.given import check_given
from cvxid.identify.loss import huber_refit
from cvxid.identify.orders import OrderSearch, search_orders
from cvxid.identify.output_error import cancelling_gain, longer_delay, natural_inertia, polish, typical_spread
from cvxid.identify.path import SELECTING, Path
from cvxid.identify.selection import Selection
from cvxid.identify.profile import profile_input_delay, with_input_tau
from cvxid.identify.problem import Problem
from cvxid.identify.stepwise import prune_by_simulation, stepwise_output_error
from cvxid.identify.system import fit_support, identified
from cvxid.metrics import HARMONICS, band_period, excess_in_band, noise_level, noise_multiple, spectral_peak
from cvxid.model.equation import LINEAR, LISTED
from cvxid.model.input_delay import record_bound
from cvxid.model.symbols import velocity_symbol
from cvxid.model.system import SystemSpec
from cvxid.parallel import engine
from cvxid.progress import progress
from cvxid.regression.builder import SystemBuilder, no_measured_velocity
from cvxid.regression.regression import Regression
from cvxid.regression.velocity import ESTIMATORS
from cvxid.regression.windows import windows_for_test
from cvxid.spec.load import load_problem
from cvxid.spec.problem import ProblemSpec


def run(spec, train=None, test=None) -> RunResult:
    """Identify the system of a problem spec (a parsed spec or a path to one).  Its
    warnings are in ``result.warnings`` (and ``result.json``), and each is issued once to
    the caller, in its own category (a :class:`~cvxid.errors.CvxidWarning`), after the run:
    a caller that turns warnings into errors gets the first as an exception.

    ``train`` and ``test`` (an :class:`~cvxid.data.experiment.Experiment` or a pandas
    DataFrame each) are records from memory in place of the spec's ``[data]``, which the
    spec may then leave out (:meth:`~cvxid.spec.problem.ProblemSpec.with_data`)."""
    if train is None and test is not None:
        raise CvxidError("run: test is given without train; pass train=… too (or neither, and the spec's [data])")
    if isinstance(spec, (str, FilePath)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CvxidWarning)  # (its notes are said with the run's warnings)
            spec = load_problem(spec, data_required=train is None)
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught, engine(spec.fit.backend, spec.fit.scheduler):
        warnings.simplefilter("always", CvxidWarning)
        if train is not None:  # (a DataFrame's sensor check warns as a file's does: in result.warnings too)
            spec = spec.with_data(train, test)
        if spec.fit.velocity == "auto":
            result = _best_velocity(spec)
        else:
            result = _identify(spec)
        _look_past_the_range(result)
        _check_given(result)
        _warn_given(result)
        _compare(result)
        _warn_confounded_gain(result)
        _warn_delay_at_bound(result)
        _warn_implausible(result)
        _warn_drift(result)
        _warn_incomplete(result)
        _warn_quiet_test(result)
        _warn_short_test(result)
    polished = (result.tau or {}).get("method") == "output_error"  # its delay supersedes the equation error's
    said = dict.fromkeys([(note, CvxidWarning) for note in spec.notes] + [
        (str(w.message), w.category) for w in caught if issubclass(w.category, CvxidWarning)
        and not (polished and issubclass(w.category, EquationErrorDelayWarning))])
    result.warnings = list(dict.fromkeys(message for message, _ in said))
    result.seconds = time.perf_counter() - start
    for message, category in said:  # to a Python caller too, once each in its own category (a notebook shows
        warnings.warn(message, category, stacklevel=2)  # them; the CLI's summary prints result.warnings instead)
    return result


def _warn_confounded_gain(out: RunResult) -> None:
    r"""An estimated feedback gain the record does not separate from the coefficient of
    its own signal, said aloud with the combination that is determined:

    * the delay's 95 % interval reaches 0: at :math:`\tau = 0` the feedback
      :math:`b\,x(t-\tau)` is the library's own column :math:`x`;
    * or the gain's 95 % interval (the profile's projection, :meth:`PolishResult.interval`)
      is wider than the gain itself: with :math:`\omega\tau` small,
      :math:`b\,x(t-\tau) \approx b\,x - b\,\tau\,\dot x`, and the gain, the stiffness,
      the damping and the delay trade along a valley of the simulation error."""
    interval = (out.tau or {}).get("interval")
    note = _added_delay_note(out)
    for model in out.system.models.values():
        spec = model.spec
        signal = spec.confounded_signal
        if signal is None:
            continue
        name, physical = spec.parameter_name(signal), model.physical
        determined = f"their difference {name} - gain = {physical[name] - physical['gain']:.4g} is"
        if cancelling_gain(model) is not None:
            warnings.warn(
                f"the feedback gain ({physical['gain']:.6g}) and {name} ({physical[name]:.6g}) nearly cancel: "
                f"{determined} what the data determine, and the two apart (with the delay, {out.system.tau:.4g} s, "
                f"and the damping) are most likely a near-collinear fit of {signal} and {signal}(t - tau), unless the "
                "system's stiffness and feedback do nearly cancel; the intervals of the gain, "
                f"{name} and the delay then describe this fit, not the system, and need not contain its values. "
                "Give the gain "
                "([model.delay] gain = …), or let the selection weigh the stiffness (a library of candidate terms "
                f"penalises the {signal} that the gain trades with, where a listed one is not)"
                + (_longer(spec) if _short_of_noise(out, spec) else "")
                + note, CvxidWarning, stacklevel=2)
        elif interval and interval[0] <= 0:
            warnings.warn(
                f"the delay's 95 % interval reaches 0 ({interval[0]:.4g} … {interval[1]:.4g} s): at tau = 0 the "
                f"feedback gain * {signal}(t - tau) is the column {signal} itself, so the gain "
                f"({physical['gain']:.4g}) and {name} ({physical[name]:.4g}), with the damping, are not identified "
                f"separately ({determined} identified; their intervals follow the fits along the delay's profile "
                "from this one, which need not reach the system's values). Give the gain ([model.delay] gain = …), "
                "or remove [model.delay] if the "
                "loop has no delay" + (_longer(spec) if _at_top(out.system.tau, spec.delay) and _short_of_noise(out, spec)
                                       else "") + note,
                CvxidWarning, stacklevel=2)
        elif out.polish is not None and _trading(out.polish):
            low, high = out.polish.interval("gain")
            k_range = (f"{name} ({physical[name]:.4g}, 95 % interval " + " … ".join(
                f"{v:.4g}" for v in out.polish.physical_interval(name)) + ")") if name in out.polish.parameters \
                else f"{name} (dropped)"
            warnings.warn(
                f"the feedback gain ({physical['gain']:.4g}, 95 % interval {low:.4g} … {high:.4g}) is not "
                f"determined apart from {k_range}: over the delay's interval they "
                f"trade, with the damping (b x(t - tau) = b x - b tau x' + ...); {determined}. Give the gain "
                "([model.delay] gain = …) if it is known, or a record whose forcing reaches higher frequencies"
                + note, CvxidWarning, stacklevel=2)


def _at_top(tau: float | None, delay) -> bool:
    """Whether the delay ``tau`` is at the top of ``delay``'s search range
    (:meth:`~cvxid.model.delay.DelayedFeedback.end`)."""
    return tau is not None and delay.end(tau) == "top"


SHORT_OF_NOISE = 1.5
"""A polished model whose free run of the training record misses it by this many times
what its noise allows (or more: :func:`_training_gap`, each coordinate of a coupled system
too) leaves something out: on the held-out benchmark's tuning seeds the polish's RMS was at
most 1.13 times the training output's noise level (0–9, 242 systems, 8 s and 5–200 s, the
gain given or estimated: docs/benchmarks.md), and the training gap, which counts the
input's noise too, 1.032 (220 runs; :data:`TRAINING_INCOMPLETE`)."""


def _short_of_noise(out: RunResult, spec) -> bool:
    """Whether the output-error polish's simulation of the training record misses it by
    :data:`SHORT_OF_NOISE` times what the noise allows for ``spec``'s coordinate or more
    (:func:`_training_gap`): the sign that a delay past its range may be what is missing,
    where a loop without feedback (its delay run to the top of the range, its gain's
    interval holding 0) fits to the noise."""
    gap = _training_gap(out, spec.coordinate)
    return gap is not None and gap >= SHORT_OF_NOISE


def _training_gap(out: RunResult, coordinate: str) -> float | None:
    """How far the final, polished model's free run misses the training record at
    ``coordinate``, in multiples of what its noise allows (:func:`_noise_multiple`); None
    without it (no polish, a diverged simulation)."""
    train = (out.train_comparisons or {}).get(coordinate)
    return None if train is None else _noise_multiple(train, train.fit_percent)


def _longer(spec) -> str:
    """The advice, for a model with a fed-back delay, that the true one may lie past its
    search range: a delay of half a period or a whole one, outside it, was fitted as a
    near-cancelling gain and stiffness (an outside check: tau 0.006 for 1.4 s) or left no
    positive inertia (3 s), and came back within 0.3 % once ``tau_max`` covered it."""
    delay = spec.delay
    if delay is None or not delay.exact:
        return ""
    return (f"; if the loop's delay may be longer than the range searched (tau_max = {delay.tau_max:g} s), raise "
            "[model.delay] tau_max and compare the fits")


def _trading(polish) -> tuple[str, ...]:
    r"""The parameters an estimated feedback gain trades with, the coefficients of the
    linear ``x`` and ``x'`` (:math:`b\,x(t-\tau) \approx b\,x - b\,\tau\,\dot x`), when
    the gain's 95 % interval is wider than the gain itself or the delay's reaches 0; ()
    otherwise.  Their own intervals are wide for that reason, not because their terms do
    not belong."""
    spec = next(iter(polish.system.models.values())).spec
    if spec.confounded_signal is None or "gain" not in polish.parameters:
        return ()
    low, high = polish.interval("gain")
    at_zero = "tau" in polish.parameters and polish.interval("tau")[0] <= 0
    if high - low <= abs(polish.parameters["gain"]) and not at_zero:
        return ()
    return tuple(name for name in map(spec.parameter_name, spec.linear_terms) if name in polish.parameters)


def _look_past_the_range(out: RunResult) -> None:
    """In a narrow-band record, the final polish's delay compared with its aliases past the
    search range (:func:`~cvxid.identify.output_error.longer_delay`), into
    ``out.polish.longer_delay``; :func:`_warn_delay_at_bound` says what it finds."""
    found = longer_delay(out.polish, [out.train]) if out.polish is not None and out.polish.profile is not None else None
    if found is not None:  # (else the polish stays the stage's own object: stepwise.final is out.polish)
        out.polish = replace(out.polish, longer_delay=found)


def _check_given(out: RunResult) -> None:
    """The values the spec gives (a mass, a feedback gain, a tie) tested against the
    training record at the final polish (:func:`~cvxid.identify.given.check_given`), into
    ``out.given``, a disagreement withdrawn where the test record's free runs contradict it;
    :func:`_warn_given` says which the record disagrees with."""
    if out.polish is not None:
        out.given = check_given(out.polish, out.train, _schedule(out.system.spec),
                                None if out.test is None else (lambda system: free_run_residual(system, out.test)))


def _disagreeing(out: RunResult) -> list:
    """The given values the record disagrees with, the best fit when freed first."""
    return sorted((c for c in out.given if c.disagrees), key=lambda c: c.rms)


def _warn_given(out: RunResult) -> None:
    """Given values the record disagrees with, each with what it becomes when estimated
    (a thirteenth outside check: a mass 10 % high moved the delay from 0.15 to 0.367 s
    and the damping by -56 %, and the run never named the mass).  Where several disagree,
    freeing any one of them may fit the record alike (a wrong mass, or the right gain
    trading with the stiffness): the run says so and leaves the choice to the reader."""
    wrong = _disagreeing(out)
    if not wrong:
        return
    several = len(wrong) > 1
    warnings.warn(
        ("the record disagrees with values the spec gives, which the fit takes as exact: freeing any one of them "
         "fits the training record better beyond chance and moves it by more than 1 % — " if several else
         "the record disagrees with a value the spec gives, which the fit takes as exact: freed, it moves by more "
         "than 1 % and the model, polished again, fits the training record better beyond chance — ")
        + "; ".join(c.sentence() for c in wrong) + (
            ". They are listed best fit first; where their errors are alike the record cannot tell which is wrong, "
            "and the one whose estimate is plausible is the suspect" if several else "")
        + ". The parameters and intervals reported hold only if every given value is right (a missing effect can "
          "also make a right value look wrong)", CvxidWarning, stacklevel=2)


def _given_note(out: RunResult, besides: tuple[str, ...] = (), passing: bool = True) -> str:
    """For a warning about the delay: the given values the record disagrees with, else
    (with ``passing``: the delay at a bound of its range) the values the spec gives that
    were checked (kinds in ``besides`` left out, the warning names them itself), which move
    the delay when wrong (a thirteenth outside check: a mass 20 % high sent the delay to
    the top of its range, and the warning said to raise it), else nothing."""
    wrong = _disagreeing(out)
    if wrong:
        return (f"; the record also disagrees with {', '.join(c.stated for c in wrong)} (the warning above), and a "
                "wrong given value moves the delay: check " + ("it" if len(wrong) == 1 else "them") + " first")
    checked = [c for c in out.given if c.kind not in besides and not c.reason] if passing else []
    if not checked:
        return ""
    held = [c.stated for c in checked if c.held]
    if held:
        return (f"; the spec also gives {', '.join(held)}, and freed, the delay stays at this end: the range, not the "
                "given value, is the likelier cause")
    given = [c.stated for c in checked]
    return (f"; the spec also gives {', '.join(given)}, which the check of given values does not fault, yet a "
            "wrong given value moves the delay too")


def _warn_delay_at_bound(out: RunResult) -> None:
    r"""A fed-back delay estimated at an end of its search range, or not determined, said
    aloud: at ``tau_max`` the true delay may be longer (unless the estimated gain's interval
    holds 0: no feedback shows; or the gain trades with its signal's coefficient, which
    :func:`_warn_confounded_gain` says: then the delay may lie anywhere); at ``tau_min`` it
    may be shorter, and at 0 a damping can stand in for a short delay
    (:math:`b\,x(t-\tau) \approx b\,x - b\,\tau\,\dot x`); an interval over
    :data:`UNDETERMINED` of the range is a flat profile.  The other parameters' standard
    errors hold at that delay only.  A delay the diagnosis added is said to be one (the
    spec has no ``[model.delay]`` to change)."""
    estimate = (out.tau or {}).get("estimate")
    spec = next(iter(out.system.models.values())).spec
    delay = spec.delay
    if estimate is None or delay is None or not delay.exact:
        return
    if out.polish is not None and out.polish.longer_delay is not None:  # (a twelfth outside check's chatter; the
        #                                    bound's warnings below would say less, about the alias)
        warnings.warn(out.polish.longer_delay.advice() + _added_delay_note(out), CvxidWarning, stacklevel=2)
        return
    end = delay.end(estimate, out.train.dt)  # (the polish's bounds hold the estimate on them)
    gain = out.polish.interval("gain") if out.polish is not None and "gain" in out.polish.parameters else None
    interval = out.tau.get("interval")
    said = spec.confounded_signal is not None and (  # (_warn_confounded_gain's)
        (interval is not None and interval[0] <= 0) or (out.polish is not None and bool(_trading(out.polish))))
    text, note = None, _given_note(out)  # (the delay at a bound: a given value may hold it there)
    top = end == "top" or (  # (or its interval reaches the top, and is not the whole range)
        interval is not None and delay.end(interval[1]) == "top" and not _spans_range(interval, delay))
    if top and said and (gain is None or gain[0] <= 0 <= gain[1]):
        # (the gain's warning says why the delay may lie anywhere in its range; a gain that is determined apart
        # from 0 feeds back, and its delay at the top may be longer: an outside check's 1.6 s, 0.46.  An eleventh
        # check's dead zone on the feedback, outside the catalogue: tau 0.5 [0.23, 0.5] for 0.15 and a softening
        # x^3 added, said only by the gain's warning)
        added = _added_effects(out)
        text = None if interval is None or interval[0] <= 0 else (  # (reaching 0: the gain's warning says it all)
            (f"the delay tau = {estimate:.4g} s sits at" if end == "top" else
             f"the delay's 95 % interval ({interval[0]:.4g} … {interval[1]:.4g} s) reaches") +
            f" the top of its search range (tau_max = {delay.tau_max:g} s): with the feedback gain not "
            "determined (above) that is the range's bound, not a measured delay, and the interval is no interval for "
            "the true one" + (f"; the diagnosis added {', '.join(added)}, which may stand in for the fed-back signal: "
                              "compare the fits without " + ("it" if len(added) == 1 else "them") if added else ""))
    elif top and gain is not None and gain[0] <= 0 <= gain[1]:
        text = (
            f"the delay tau = {estimate:.4g} s is at the top of its search range and the feedback gain's 95 % "
            f"interval ({gain[0]:.4g} … {gain[1]:.4g}) contains 0: the data show no fed-back signal to delay; remove "
            "[model.delay] (or give its gain if the loop is known to feed back)")
    elif top:
        text = (
            f"the delay tau = {estimate:.4g} s" + (f" (95 % interval {interval[0]:.4g} … {interval[1]:.4g} s)"
                                                  if interval else "") +
            f" reaches the top of its search range (tau_max = {delay.tau_max:g} s): the true delay may be longer; "
            "raise [model.delay] tau_max" + _stand_ins(out))
    elif end == "bottom" and delay.tau_min > 0:
        text = (
            f"the delay tau = {estimate:.4g} s is at the bottom of its search range (tau_min = {delay.tau_min:g} s): "
            "the true delay may be shorter; lower [model.delay] tau_min")
    elif end == "bottom" and spec.confounded_signal is None:  # (at 0; else _warn_confounded_gain says it)
        note = _given_note(out, ("gain",))  # (this warning names a given gain itself)
        text = (
            f"the delay tau = {estimate:.4g} s is at 0, the bottom of its search range: the data show no delay, or "
            "another term stands in for it (for a short delay b x(t - tau) = b x - b tau x' + ..., a damping); the "
            "other parameters' standard errors hold at tau = 0 only. Give the delay a floor ([model.delay] tau_min) "
            "if the loop is known to be late, or a longer, richer record" + (
                f". The gain is given ({', '.join(f'{g:g}' for g in delay.gains)}): a given gain of the wrong sign or "
                "size also sends the delay "
                "to 0, the stiffness absorbing the feedback (at tau = 0 it is the column x itself); leave the gain "
                "out of [model.delay] to estimate it and compare" if delay.gain is not None else ""))
    elif _spans_range(interval, delay) and not said:
        note = _given_note(out, passing=False)  # (at no bound: only a value the record disagrees with)
        text = (
            f"the delay is not determined by these data: its 95 % interval {interval[0]:.4g} … {interval[1]:.4g} s "
            f"spans most of the search range {delay.tau_min:g} … {delay.tau_max:g} s, so the estimate {estimate:.4g} "
            "s is one point of a flat profile (the report's delay_profile.png shows it) and the other parameters hold "
            "at that delay only. " + ("Give the gain if it is known ([model.delay] gain), or a" if delay.gain is None
                                      else "Give a") +
            " longer record, or one whose forcing reaches the frequencies where the delay shifts the phase")
    if text is not None:
        warnings.warn(text + note + _added_delay_note(out), CvxidWarning, stacklevel=2)


def _added_effects(out: RunResult) -> list[str]:
    """The terms the diagnosis added, by equation error and by simulation error."""
    added = [s.term for s in (out.refinement.steps if out.refinement is not None else [])]
    return added + [s.term for s in (out.simulation_refinement.steps if out.simulation_refinement is not None else [])
                    if s.kept]


def _stand_ins(out: RunResult) -> str:
    """For a delay held at the top of its range: the effects the diagnosis added, which may
    stand in for the longer delay (an outside check's delay of 4 s, searched up to 0.5 s,
    had a Coulomb friction added beside it), else nothing."""
    added = _added_effects(out)
    if not added:
        return ""
    return (f"; the diagnosis added {', '.join(added)}, which may stand in for the longer delay: run again with the "
            "longer range before trusting " + ("it" if len(added) == 1 else "them"))


def _added_delay_note(out: RunResult) -> str:
    """For the warnings about a delay: that the diagnosis added it (its spec has no
    ``[model.delay]`` to change), else nothing."""
    start = out.refinement.start if out.refinement is not None else None
    delay = next(iter(out.system.models.values())).spec.delay
    if start is None or delay is None or all(s.delay is not None for s in start.specs.values()):
        return ""
    return (f" (this delay was added by the diagnosis, searched in [0, {delay.tau_max:g}] s: to set its range or gain, "
            "write it into the spec as a [model.delay] table)")


UNDETERMINED = 0.5
"""A delay whose 95 % interval covers this share of its search range is not determined."""


def _spans_range(interval, delay) -> bool:
    """Whether a delay's interval covers :data:`UNDETERMINED` of ``[tau_min, tau_max]``."""
    if not interval or not np.all(np.isfinite(interval)):
        return False
    return interval[1] - interval[0] >= UNDETERMINED * (delay.tau_max - delay.tau_min)


def _warn_implausible(out: RunResult) -> None:
    """A model no physical system has, said aloud: a negative inertia, one at its lower
    bound (an input of the wrong sign), a negative net damping, a selection that
    dropped every candidate term at the top of the lambda grid (unless listed or kept
    linear terms explain the data: :data:`EXPLAINED`), or one that kept every candidate at
    its bottom."""
    for label, model in out.system.models.items():
        mass = model.physical.get("m")
        where = "" if len(out.system.models) == 1 else f" of equation '{label}'"
        if model.spec.inertia and mass is not None and not mass >= 0:
            warnings.warn(
                f"the identified inertia{where} is {mass:.4g}, {'negative' if mass < 0 else 'not a number'}: no "
                "physical system has it (nor can it be "
                f"simulated). Constrain it ([model.constraints] nonnegative = [\"{model.spec.inertia_term.name}\"]), "
                "keep the windowed integrals (window = \"auto\") on long records, or check the data", CvxidWarning,
                stacklevel=2)
        elif model.spec.inertia and mass is not None and mass <= INERTIA_AT_BOUND * _natural_inertia(model.spec,
                                                                                                     out.train):
            spec = model.spec
            flipped = spec.input[1:].strip() if spec.input.startswith("-") else f"-{spec.input}"
            warnings.warn(
                f"the identified inertia{where} is {mass:.3g}, at its lower bound (next to 0): its force is under "
                f"{INERTIA_AT_BOUND:g} of the input's at the record's fastest motion, so a positive inertia does not "
                f"fit these data. Check the input's sign (a sensor mounted the other way round: "
                + (f"[model] input = \"{flipped}\"" if len(out.system.models) == 1 else
                   f"input = \"{flipped}\" in the [[model.equation]] of '{label}'") +
                f"), that '{spec.input}' is the signal that drives '{spec.coordinate}' (not a "
                "command the actuator saturates or lags), and the time column's unit" + _longer(spec), CvxidWarning,
                stacklevel=2)
        own = out.spec.equations.get(label)  # (the spec's own: the diagnosis lists and signs what it adds)
        held = [n for n in (own.listed if own is not None else ()) if n in own.nonnegative
                and out.system.coefficients.get(out.system.column(label, n), 0.0) == 0.0]
        if held:  # (an eleventh outside check: sign(x') listed and constrained, 0 in the model, a footnote saying
            #        it was a parameter given in the spec)
            it = "it" if len(held) == 1 else "them"
            warnings.warn(
                f"{', '.join(held)}{where}, listed in the spec, {'is' if len(held) == 1 else 'are'} 0: held at "
                f"{'its' if len(held) == 1 else 'their'} sign constraint's bound ([model.constraints] nonnegative), "
                f"so the data ask for the other sign or for none of {it}; the model leaves {it} out (no interval)",
                CvxidWarning, stacklevel=2)
    if out.polish is not None:
        _warn_undetermined(out.polish)
        _warn_diverged_profile(out.polish)
        _warn_negative_damping(out)
    if out.path is None or out.lam is None or out.problem is None:
        return
    candidates = (out.problem.penalties > 0) & ~out.problem.held_by_ties  # (a tie keeps those: Path.open_edge)
    chosen = np.array([out.system.coefficients.get(n, 0.0) != 0 for n in out.problem.names])
    if candidates.sum() > 2 and (chosen | ~candidates).all() and out.lam <= out.path.lambdas.min():
        warnings.warn(
            f"the selection kept every one of the {int(candidates.sum())} candidate terms: lambda = {out.lam:.3g} is "
            "the bottom of its grid, so the validation error was least with no term dropped; the data do not tell "
            "which terms are needed (give a longer or richer record, a test record, or fewer candidates)",
            CvxidWarning, stacklevel=2)
    kept = any(c.group in (LISTED, LINEAR) for m in out.system.models.values() for c in m.spec.columns)
    if candidates.any() and not (chosen & candidates).any() and out.lam >= out.path.lambdas.max() \
            and not (kept and _explained(out) >= EXPLAINED):
        warnings.warn(
            f"the selection dropped every candidate term: lambda = {out.lam:.3g} is the top of its grid, so the "
            "validation error was least with no term at all; the model is likely missing an effect or the data "
            "do not excite it (run the diagnosis, [diagnose], or give the terms you expect)", CvxidWarning,
            stacklevel=2)


INERTIA_AT_BOUND = 1e-4
"""An identified inertia at most this share of its natural size
(:func:`~cvxid.identify.output_error.natural_inertia`) sits at its bound: the data ask for
a negative one (an input of the wrong sign, or not the one driving the output)."""


def _natural_inertia(spec, train: Experiment) -> float:
    """The natural size of ``spec``'s inertia on the training record."""
    output = train.output(spec.coordinate)
    return natural_inertia(typical_spread(spec.received_input(train)), typical_spread(output),
                           band_period([output], train.dt))


EXPLAINED = 0.5
"""A selection that keeps no candidate is an answer when the listed or kept linear terms
explain at least this share of the training equation's target (a linear system), and a
warning when they do not (an output the input does not drive)."""


def _explained(out: RunResult) -> float:
    r"""The share of the training regression's target that the final coefficients
    explain, :math:`1 - \|Pc - p\|^2 / \|p\|^2`."""
    reduced = out.problem.reduced
    c = np.array([out.system.coefficients.get(n, 0.0) for n in out.problem.names])
    return 1.0 - reduced.mse(c * reduced.column_scale / reduced.target_scale) / reduced.target_scale ** 2


def _warn_negative_damping(out: RunResult) -> None:
    """A linear damping whose output-error 95 % interval lies below 0, said aloud: the
    model feeds energy in at low speeds, which a passive system does not (a real record's
    damping read -0.036, its interval -0.044 … -0.010, with no word)."""
    one = len(out.system.models) == 1
    for label, model in out.system.models.items():
        spec = model.spec
        term = velocity_symbol(spec.coordinate)
        name = spec.parameter_name(term) if one else f"{label}:{term}"
        if name not in out.polish.parameters or name in out.polish.states:
            continue
        low, high = out.polish.interval(name)  # (the coefficient of x' itself, whatever its physical name's sign)
        value = out.polish.parameters[name]
        if high < 0 and _net_damping(model, value) < 0:
            warnings.warn(
                f"the damping, the coefficient of {term}, is {value:.3g} (95 % interval {low:.3g} … {high:.3g}), "
                "negative: the model feeds energy in at low speeds. A passive system has no such term: constrain it "
                f"([model.constraints] nonnegative = [\"{term}\"]) or look for the effect it stands in for (a "
                "friction, a delay, a force the input misses); a driven or controlled system may have it",
                CvxidWarning, stacklevel=2)


def _net_damping(model, damping: float) -> float:
    r"""The linear damping with the fed-back delay's share: a feedback
    :math:`b\,x(t - \tau) \approx b\,x - b\tau\,\dot x` on the right-hand side adds
    :math:`b\tau`, one of the velocity :math:`b\,\dot x(t - \tau)` takes :math:`b`, both at once
    (the paper's) :math:`b_0\tau - b_1` (a real record's damping of -1.50 beside
    :math:`35.7\,\theta(t - 0.0445)` is +0.09 net)."""
    delay = model.spec.delay
    if delay is None or delay.coordinate != model.spec.coordinate:
        return damping
    system = model.system()
    gain, tau = float(system.gain), float(model.tau or 0.0)
    return damping + gain * tau - float(system.rate_gain) if delay.derivative == 0 else damping - gain


def _warn_undetermined(polish) -> None:
    """Coefficients whose output-error 95 % interval contains 0: the data do not show their
    terms (the delay is left to :func:`_warn_confounded_gain`)."""
    trading = _trading(polish)
    loose, said = [], ("tau", "tau_u", *(("gain", *trading) if trading else ()))  # (_warn_confounded_gain's)
    for name, value in polish.parameters.items():
        if name in said or name in polish.states:
            continue
        low, high = polish.physical_interval(name)
        if low <= 0 <= high:
            value = -value if polish.negated(name) else value
            loose.append(f"{name} ({value:.3g}, 95 % interval {low:.3g} … {high:.3g})")
    if loose:
        warnings.warn(  # (the polish fits the training record alone: an eleventh outside check's small training
            #              motion left k3 at 0.999 [-2.8, 4.8] for 1 where the test record's large one needs it)
            f"the training record does not determine {', '.join(loose)}: each 95 % interval contains 0, so either "
            "these terms do not belong in the model or this record does not excite them (too small or too slow a "
            "motion for them to show); a richer training record tells which, or remove them and compare the test "
            "fits", CvxidWarning, stacklevel=2)


def _warn_diverged_profile(polish) -> None:
    """The output-error delay profile's fits that diverged just outside the delay's
    interval, said aloud: the model cannot be simulated at those delays, so the profile does
    not say how far the interval would reach; it is taken to reach them (a ninth outside
    check's disk, its gain free: every delay but 0 diverged, and the interval read
    0 … 0)."""
    profile = polish.profile
    if profile is None or profile.method != "output_error":
        return
    diverged = ~np.isfinite(profile.values)
    if not diverged.any():
        return
    low, high = profile.interval  # the delays just outside it bound it where their fits diverged
    inside = np.flatnonzero((profile.taus >= low) & (profile.taus <= high) & ~diverged)
    if inside.size == 0:
        return
    near = [j for j in (inside[0] - 1, inside[-1] + 1) if 0 <= j < profile.taus.size and diverged[j]]
    if near:
        printed = polish.interval("tau")  # (the printed one, with the standard error's part: a twelfth outside
        #                                    check read 0.075 … 0.07625 here and 0.065 … 0.087 printed)
        warnings.warn(
            f"the output-error fits diverged at {int(diverged.sum())} of the {profile.taus.size} delays of the "
            f"profile, at the edge of the delay's interval ({', '.join(f'{profile.taus[j]:.4g}' for j in near)} "
            "s): the model "
            "cannot be simulated there, so the delay's 95 % interval "
            f"({printed[0]:.4g} … {printed[1]:.4g} s) is taken to reach them and says nothing "
            "beyond. An estimated gain that destabilises the loop at any other delay is the usual cause: give "
            "the gain ([model.delay] gain = …) or a narrower delay range", CvxidWarning, stacklevel=2)


DRIFT = 10.0
r"""A free run drifts when its error on the test record is at least this many times both
what the noise allows and the :math:`k`-step-ahead prediction's error (each as
:math:`100 - \text{fit}\,\%`)."""


def _warn_drift(out: RunResult) -> None:
    r"""A final model whose free run of the test record misses it by an order of magnitude
    more than its noise allows while its :math:`k`-step-ahead prediction is close, said
    aloud: each step is right and the run drifts away, the sign of a basin of the
    simulation error away from the data (a long record fitted from a poor start), of a
    missing effect whose small force adds up (a hidden quadratic stiffness at noise 0.001),
    or of a model that is too sensitive to simulate.  On the held-out benchmark's tuning seeds
    (100 systems, 5–200 s) one fit did this (57 times the noise's error, 1.06 times for the
    prediction); the other 99 ran within 1.2 times; the unbalanced disk's recording, whose
    model misses some of its dynamics, 15.7 and 2.9 times."""
    drifting = {label: c for label, c in (out.comparisons or {}).items() if _drifts(c)}
    before = _before_polish(out) if drifting else {}
    for label, c in drifting.items():
        where = "" if len(out.comparisons) == 1 else f" of '{label}'"
        warnings.warn(
            f"the free run{where} drifts away from the test record: fit {_percent(c.fit_percent)} % where the "
            f"noise allows {_percent(c.ceiling_percent)} %, while its {c.k_step}-step-ahead prediction fits "
            f"{_percent(c.k_step_fit_percent)} %; each step is right and the simulation is not, so the fit "
            "stopped in a basin of the simulation error away from the data (on a long record: identify a "
            "shorter stretch first, or give the delay a narrower range), or the model lacks part of the "
            "dynamics, a small force each step that adds up over a free run (an effect the diagnosis did not "
            "find, or outside its catalogue), or the sensor drifts slowly (an offset that wanders: no model term "
            "follows it; high-pass the record, or fit a shorter stretch), or it is too sensitive to simulate; read its "
            "parameters with care"
            + _astray(c, before.get(label)) + (f". Of the catalogue, {refused}" if (refused := _refused(out)) else ""),
            CvxidWarning, stacklevel=2)


ASTRAY = 2.0
r"""A polish went astray when the model it started from misses the test record's free run
by at most :math:`1/\text{ASTRAY}` of the polished model's error (each as
:math:`100 - \text{fit}\,\%`)."""


def _before_polish(out: RunResult) -> dict:
    """The test record's comparisons of the model the output-error polish started from
    (coordinate → :class:`~cvxid.diagnosis.compare.Comparison`), or none without a polish."""
    if out.unpolished is None or out.test is None:
        return {}
    return compare_system(out.unpolished, out.test)


def _astray(c, start) -> str:
    """The sentence a drift warning adds when the model the polish started from (its
    comparison ``start``) fits the test record's free run better by :data:`ASTRAY` or more
    (a long record's simulation error, far from its start, has basins away from the data: a
    held-out tuning system of 115 s, 90.5 % before the polish, -105 % after)."""
    if start is None or start.fit_percent is None or not start.fit_percent > 0:
        return ""
    if c.fit_percent is not None and ASTRAY * (100.0 - start.fit_percent) > 100.0 - c.fit_percent:
        return ""
    return (f". The equation-error model the output-error polish started from fits it {_percent(start.fit_percent)} "
            "%: the polish went astray on the training record (its free run from that start is far from the "
            "data over a long record); fit a shorter stretch of it, or keep that model with [fit] refine = \"none\"")


def _noise_multiple(c, fit: float | None) -> float | None:
    r"""A simulation's error on a record (``fit``, %, of the comparison ``c``) in
    multiples of what its noise allows (:func:`~cvxid.metrics.noise_multiple`)."""
    return noise_multiple(fit, c.ceiling_percent)


def _drifts(c) -> bool:
    """Whether the free run of comparison ``c`` misses the test record by :data:`DRIFT`
    times what the noise allows and its k-step prediction's error (:func:`_warn_drift`)."""
    free, ahead = _noise_multiple(c, c.fit_percent), _noise_multiple(c, c.k_step_fit_percent)
    return None not in (free, ahead) and free >= DRIFT * max(ahead, 1.0)


INCOMPLETE = 2.0
r"""A final model is incomplete when its free run misses the test record by at least this
many times what the noise allows (:math:`(100 - \text{fit}) / (100 - \text{ceiling})`, the
ratio of the free run's error to the noise's)."""

IN_BAND = 0.5
"""The share of a training record's free-run error beyond white noise that must lie in the
motion's band (:func:`~cvxid.metrics.excess_in_band`) for its gap to be read as a missing
force; less is a noise that is not white (:func:`_warn_incomplete`)."""

TRAINING_INCOMPLETE = 1.1
r"""A polished model may be incomplete when its free run misses the training record it
was fitted on by at least this many times what the noise allows (the ratio of
:data:`INCOMPLETE`): the fitted record is long and the fit's own initial state is exact for
it, so the ratio of a complete model stays near 1.  On the held-out benchmark's tuning
seeds (0–9, noise 0.01 and 0.001, 220 runs: every catalogue effect found by the diagnosis
from 8 s, and the true terms given on 5–200 s) complete models under white noise reached
1.032 at most; effects outside the catalogue (``examples/incomplete_models.py``) left
medians of 1.02–1.08 at noise 0.01 (the catalogue's neighbours stand in for most of them)
and 2.5–4.2 at 0.001.  A noise that is not white raises it too (:func:`_warn_incomplete`)."""


def _warn_incomplete(out: RunResult) -> None:
    r"""A final model whose free run misses the test record by :data:`INCOMPLETE` times
    what the noise allows or more (and does not drift, which :func:`_warn_drift` says), or
    the training record by :data:`TRAINING_INCOMPLETE` times, said aloud: part of the
    dynamics is not in the model and the diagnosis found no candidate that holds it.  An
    outside check's dead-zone spring (2.3 times), Stribeck and Dahl frictions (2.5 and 3.5
    times) and a second, unmodelled input (8.9 times) ended with no word between the drift's
    10 times and nothing; a fourteenth's stiffness :math:`x|x|` fitted as :math:`x^3`
    missed its test record by 1.5 times and its training record by 2.3 times.  Where the
    training record's gap alone is past its threshold the warning says the dynamics *may*
    be incomplete, or the noise not white: a complete model under a mains hum or a filtered
    sensor's noise (a review: 1.09–1.25 times) is told from a missing effect by neither
    gap, but by where the excess lies (:func:`~cvxid.metrics.excess_in_band`: a hum's or a
    filtered noise's above the motion's band), and the run then says the noise is not
    white instead."""
    tests, trains = out.comparisons or {}, out.train_comparisons or {}
    for label in dict.fromkeys([*tests, *trains]):
        test, train = tests.get(label), trains.get(label)
        free = None if test is None else _noise_multiple(test, test.fit_percent)
        fitted = _training_gap(out, label)
        over_test = free is not None and free >= INCOMPLETE
        if test is not None and _drifts(test) or not (over_test or fitted is not None and fitted >= TRAINING_INCOMPLETE):
            continue
        where = "" if len(tests or trains) == 1 else f" of '{label}'"
        inside = None if over_test else excess_in_band(train.measured, train.free_run, out.train.dt,
                                                        noise_level(train.measured))
        if inside is not None and inside < IN_BAND:
            warnings.warn(
                f"the final model's free run{where} misses the training record it was fitted on by {fitted:.3g} times "
                f"what white noise of its level allows (fit {_percent(train.fit_percent)} % where the noise allows "
                f"{_percent(train.ceiling_percent)} %), but {100 * (1 - inside):.3g} % of the excess lies above the "
                f"motion's band (above {HARMONICS:g} times its band edge), where a missing force does not reach: the "
                "measurement noise is not white (a mains hum, a sensor's filter), and the noise ceilings printed, "
                "which assume white noise, are too high", CvxidWarning, stacklevel=2)
            continue
        tried = (_refused(out) or "no candidate the diagnosis tried holds it" if out.spec.diagnose is not None
                 else "[diagnose] looks for it among the catalogue's effects")
        claim = "part of the dynamics is not in the model" if over_test else (
            f"part of the dynamics may be missing from the model ({100 * inside:.3g} % of the excess over white noise "
            "lies in the motion's band, where a missing force errs), or the noise is not white there")
        warnings.warn(
            f"the final model's free run{where} misses " + _gap_records(test, free, train, fitted)
            + f": {claim}, and {tried}. Effects outside the "
            "catalogue leave such a gap (a friction with memory or a Stribeck decay, a dead zone or backlash, "
            "an actuator's lag or saturation, a second input), as do a delay outside its search range, a second "
            "loop with its own delay, a parameter that drifts over the record (fit its halves apart and compare), "
            "a fit stopped in a wrong basin of the simulation error (a complete model whose delay and gain are far "
            "off: fit again from another start or a narrower delay range) and a noise that is not white"
            + _jumping(out.test) + ("" if test is None else _coarse(test, out.test))
            + ("; test_fit.png shows where it fails, and" if test is not None else ";")
            + " cvxid.residuals(model, test).binned(\"velocity\") (or \"position\") "
            "against which state" + (". The 95 % intervals assume a complete model: with a part missing, the "
                                     "parameters move with the stretch of data they are fitted on by more than "
                                     "the intervals say (fit another stretch to see how much)"
                                     if out.polish is not None else ""), CvxidWarning, stacklevel=2)


def _gap_records(test, free: float | None, train, fitted: float | None) -> str:
    """The gap warning's figures: the records whose free run is past its threshold, each
    with its fit against what its noise allows, then the other record's gap as context."""
    records = [(test, free, INCOMPLETE, "the test record", "the test record"),
               (train, fitted, TRAINING_INCOMPLETE, "the training record it was fitted on", "the training record")]
    past = [gap is not None and gap >= threshold for _, gap, threshold, _, _ in records]
    said = ", and ".join(f"{name} by {gap:.3g} times what its noise allows (fit {_percent(c.fit_percent)} % where "
                         f"the noise allows {_percent(c.ceiling_percent)} %)"
                         for (c, gap, _, name, _), over in zip(records, past) if over)
    within = "".join(f" ({short}: {gap:.3g} times)"
                     for (_, gap, _, _, short), over in zip(records, past) if gap is not None and not over)
    return said + within


def _refused(out: RunResult) -> str:
    """What the gap warning says of a candidate the diagnosis refused although it lowered
    the test equation error (a ninth outside check: on 8 s of stick-slip a Coulomb friction
    ranked first, refused, and the warning named only effects outside the catalogue; given
    by hand, the friction fitted to the noise), else nothing."""
    stopped = out.refinement.stopped if out.refinement is not None else None
    if not stopped or not stopped["validation_ratio"] > 1 or not out.refinement.diagnoses:
        return ""
    ranking = out.refinement.diagnoses[-1].ranking
    helping = ranking[ranking["validation_ratio"] > 1].head(REFUSED)
    tries = ", ".join(f"{row.term} ({effect}, {row.validation_ratio:.3g})" for effect, row in helping.iterrows())
    return (f"the diagnosis {stop_reason(stopped)}; a refused candidate that lowers the test equation error may "
            f"still be the missing part: add its term to the model's terms, one at a time, and compare the test "
            f"fits ({tries}: the term, its effect and how many times it lowered the test equation error)")


REFUSED = 3
"""The candidates the gap warning lists, those that lowered the test equation error, best
first (:func:`_refused`)."""


COARSE = 8.0
"""Samples a period of the output's band edge (:func:`~cvxid.metrics.band_period`) under
which the gap warning names the sample step.  Measured on one record, the unbalanced disk
(a ninth outside check): at its 40 Hz, 18 samples a period, and every second sample, 9,
identify alike; every fourth, 4.6, loses its friction and doubles its damping."""


def _coarse(compared, test) -> str:
    """What the gap warning adds when the test record is sampled coarsely against its
    motion (:data:`COARSE`), else nothing."""
    if test is None:
        return ""
    samples = band_period([compared.measured], test.dt) / test.dt
    if samples >= COARSE or samples <= 2.0 + 1e-9:  # (2: the band edge at Nyquist, a record of noise: no word)
        return ""
    return (f", and a sample step coarse against the motion ({samples:.2g} samples a period of the output's band "
            f"edge; the derivatives and the frictions' switching need more: sample faster, {COARSE:g} or more)")


def _jumping(test) -> str:
    """What the gap warning adds when the test record's input jumps between level stretches
    (:func:`~cvxid.data.hold.looks_held`: a square wave, steps, a PRBS): where a jump falls
    between two samples the record cannot say when, and a true model misses by a few times
    the noise's error (a seventh outside check: the flexible joint's true model, 3.1 times on
    its square-wave test, at the noise on a sine)."""
    for name, u in (test.inputs.items() if test is not None else ()):
        if looks_held(u[np.isfinite(u)]):  # (its gaps' samples left out)
            return (f", and an input that jumps ('{name}' on the test record: a square wave or steps), whose jumps "
                    "fall between samples at times the record cannot tell (a true model then misses by a few times "
                    "the noise's error; a smooth test input tells the two apart)")
    return ""


def _percent(fit: float) -> str:
    """A fit (%) with the decimals that tell it from 100 (99.99993 is not "100.0")."""
    gap = 100.0 - fit
    if gap <= 0:
        return f"{fit:g}"
    return f"{fit:.{1 if gap >= 0.1 else min(12, int(np.ceil(-np.log10(gap))) + 1)}f}"


QUIET = 90.0
"""A test record on which a perfect model would fit less than this (%, the noise's
ceiling) barely moves above its noise."""


def _warn_quiet_test(out: RunResult) -> None:
    """A test record whose output barely moves above its noise (the fit a perfect model
    would reach under :data:`QUIET`), said aloud: its figures, and the diagnosis's choices
    made on it, rest on little (an outside check's step response, whose last fifth had
    settled: a perfect model would fit 83.3 %)."""
    for label, c in (out.comparisons or {}).items():
        if c.ceiling_percent is not None and c.ceiling_percent < QUIET:
            where = "" if len(out.comparisons) == 1 else f" ('{label}')"
            warnings.warn(
                f"the test record's output{where} barely moves above its noise (the noise is over a tenth of its "
                f"spread): a perfect model would fit only {c.ceiling_percent:.1f} % of it, so its figures, and the "
                "diagnosis's choices made on it, rest on little; give a test record with more motion (or less "
                "noise)",
                CvxidWarning, stacklevel=2)


def _warn_short_test(out: RunResult) -> None:
    """A test record shorter than one period of the training response's dominant oscillation
    (its spectral peak, :func:`~cvxid.metrics.spectral_peak`), said aloud: its free run tests
    a fraction of a swing, and the diagnosis's choices made on it rest on little (a twelfth
    outside check's 0.4 s test record, under half a period, passed without a word beside a
    fit of −647 % from the record's own start)."""
    if out.test is None:
        return
    length = float(out.test.time[-1] - out.test.time[0])
    coordinate = next(iter(out.system.specs.values())).coordinate
    period = spectral_peak(out.train.output(coordinate), out.train.dt).period
    if length < period:
        warnings.warn(
            f"the test record spans {length:.3g} s, less than one period ({period:.3g} s) of the training "
            "response's spectral peak (its slowest strong motion, an oscillation or a slow drift of an overdamped "
            "plant): its free run tests a fraction of that motion, so its fit, and the "
            "diagnosis's choices made on it, rest on little; give a longer test record ([data.test] fraction or "
            "samples)", CvxidWarning, stacklevel=2)


def _best_velocity(spec) -> RunResult:
    """``velocity = "auto"``: identify with each estimator, keep the least test error."""
    if "test" not in spec.data:
        raise CvxidError('velocity = "auto" chooses by the test error: add [data.test]')
    scores, best = {}, None
    for name in progress(ESTIMATORS, "velocity auto: one identification per estimator"):
        result = _identify(replace(spec, fit=replace(spec.fit, velocity=name)))
        scores[name] = result.test_mse
        if best is None or result.test_mse < best.test_mse:
            best = result
    best.velocity_scores = scores
    return best


CV_FOLDS = 5
"""Blocked cross-validation folds that choose lambda when the spec has no test experiment."""


def _check_measured_velocity(system: SystemSpec, records: dict) -> None:
    """A clear error when ``[fit] velocity = "measured"`` finds a record without a
    coordinate's measured velocity (a seventh outside check: accepted without a word
    where no term read it, an error naming neither key where one did)."""
    for which, e in records.items():
        missing = [s.coordinate for s in system.equations.values() if e is not None and s.coordinate not in e.velocities]
        if missing:
            raise CvxidError(no_measured_velocity(f"[data.{which}]", which, missing))


def _identify(spec) -> RunResult:
    fit = spec.fit
    system = spec.system
    if fit.estimator == "stepwise_oe" and (fit.orders or fit.bootstrap or spec.diagnose is not None
                                           or fit.loss != "squared"):
        raise CvxidError('estimator = "stepwise_oe" selects the terms itself: remove [fit] orders, bootstrap and '
                         'loss, and [diagnose]')
    if fit.estimator == "stepwise_oe" and any(spec.listed for spec in system.equations.values()):
        raise CvxidError('estimator = "stepwise_oe" selects terms, but the listed terms are estimated, never '
                         'selected: add [model.library] select = true, or use estimator = "lstsq"')
    train = spec.experiment("train")
    test = spec.experiment("test") if "test" in spec.data else None
    if test is not None:
        spec.warn_overlap(train, test)
    velocity = fit.velocity if fit.velocity in ESTIMATORS else "measured"
    if velocity == "measured":
        _check_measured_velocity(system, {"train": train, "test": test})
    if fit.orders:
        system = spec.at_order(system, max(fit.orders))
    system = _bounded_input_delay(system, train)
    _check_input_delay(system, [train] + ([test] if test else []))
    rows = SystemBuilder(system.equations, train, velocity, fit.window, fit.allow_large)
    test_rows = SystemBuilder(system.equations, test, velocity,
                              windows_for_test(fit.window, rows.window, system.equations.values(), test),
                              fit.allow_large) if test else None
    whole = fit_support(system, rows, solver=fit.solver) if system.exact else None
    input_profile = None
    if any(s.input_delay is not None and s.input_delay.free for s in system.equations.values()):
        system, input_profile = _estimate_input_delay(system, rows, whole.tau if whole else None, fit.solver)
        whole = fit_support(system, rows, solver=fit.solver) if system.exact else None
    if fit.estimator == "stepwise_oe":
        return _stepwise(spec, system, rows, test_rows, train, test)
    whole_system = system
    tau = whole.tau if whole else None
    regression = rows.at(tau, system.equations)
    validation = test_rows.at(tau, system.equations) if test else None
    search = None
    if fit.orders:
        search = order_search(spec, fit.orders, train=regression, test=validation, boot=fit.bootstrap)
        system = spec.at_order(system, search.best_order)
        regression = regression.subset(system.column_names)
        validation = validation.subset(system.column_names)
    problem = Problem.from_regression(regression, system.nonnegative, fit.solver, ties=system.ties)
    # lambda by the test error, or without a test experiment by blocked cross-validation over time
    folds = CV_FOLDS if validation is None and fit.estimator != "lstsq" else None
    stable = None
    if fit.estimator == "lstsq":  # every fit is one: least squares on every column
        path = Path.compute(problem, fit.lambdas, validation.residual if validation else None, "lstsq")
        best = chosen = path.fits[-1]
        keep = best.support | (problem.penalties == 0)
    else:  # (the bootstrap selects on each of its samples and its mean is the estimate)
        stability = fit.stability if not fit.bootstrap else None
        choice = Selection(fit.estimator, fit.lambdas, fit.selection, stability).choose(
            problem, validation.residual if validation else None, folds, fit.debias)
        path, best, keep, stable, chosen = choice.path, choice.fit, choice.keep, choice.stability, choice.reported
    taken = stable is not None and stable.accepted
    coefs = dict(zip(problem.names, np.where(keep, chosen.coefficients, 0.0)))
    ensemble = None
    if fit.bootstrap:
        ensemble = search.ensembles[search.best_order] if search else bootstrap(
            regression, fit.lambdas, validation.residual if validation else None, fit.bootstrap,
            system.nonnegative, fit.solver, fit.estimator, fit.debias, fit.selection, ties=system.ties,
        )
        coefs = dict(ensemble.mean)  # the paper's estimate (its eq. 18)
        keep = np.array([coefs[n] != 0 for n in problem.names])
        if system.exact:  # refitted on a support below: the terms most samples chose (any sample's kept every term
            keep = (ensemble.inclusion.to_numpy() >= 0.5) | (problem.penalties == 0)  # one block sample picked)
    profile = None
    if system.exact:
        same = keep.all() and system is whole_system  # the whole library's profile is this support's
        refit = fit_support(system, rows, keep, solver=fit.solver, profile=whole.profile if same else None)
        tau, profile, coefs = refit.tau, refit.profile, refit.coefficients
        validation = test_rows.at(tau, system.equations) if test else None
    if fit.loss == "huber":
        robust, _ = huber_refit(rows.at(tau, system.equations), keep, system.nonnegative, fit.solver,
                                ties=system.ties)
        coefs = dict(zip(problem.names, np.where(keep, robust.coefficients, 0.0)))
    selects = fit.estimator != "lstsq" and bool(problem.penalties.any())  # listed terms only: nothing to select
    lam = best.lam if selects else 0.0  # least squares: no penalty, nothing selected
    info = {"method": "equation_error", "lambda": lam, **({"support": "stability selection"} if taken else {})}
    if profile is not None:
        info["tau_interval"] = list(profile.interval)
    result = identified(system, {n: float(c) for n, c in coefs.items()}, tau, lam, profile, info)
    tau_info = None if profile is None else profile.as_dict()
    if ensemble is not None:
        if system.exact:  # each sample's delay profiled again on its rows: its error spreads into the coefficients
            ensemble = with_delays(ensemble, lambda t: rows.at(t, system.equations),
                                   (rows.delay.tau_min, rows.delay.tau_max), system.nonnegative, system.ties)
        delays = ensemble.taus if ensemble.taus is not None else [tau] * len(ensemble.coefficients)
        ensemble.physical = pd.DataFrame([identified(system, dict(r), t).physical
                                          for (_, r), t in zip(ensemble.coefficients.iterrows(), delays)])
        if "tau_u" in ensemble.physical and input_profile is not None:  # an input's delay is held in the samples:
            ensemble.physical["tau_u"] = np.nan                      # no spread to give (its profile has one)
    if system.delay is not None and not system.exact:  # (a Taylor delay: one equation)
        interval = None
        if ensemble is not None:
            taus = ensemble.physical["tau"]
            interval = [float(taus.quantile(0.025)), float(taus.quantile(0.975))]
        tau_info = {"estimate": result.physical["tau"], "interval": interval, "method": "taylor"}
    out = RunResult(spec, result, None if fit.estimator == "lstsq" else path, problem, train, test, float("nan"),
                    float("nan"), bootstrap=ensemble, order_search=search, tau=tau_info, stability=stable,
                    lam=best.lam if selects else None, window=rows.window,
                    input_delay=None if input_profile is None else input_profile.as_dict())
    if spec.diagnose is not None:
        rows, test_rows = _diagnose(spec, out, rows, test_rows, velocity)
    if fit.refine == "output_error":
        _polish(out, rows)
    _score(out, test_rows)
    return out


def _bounded_input_delay(system: SystemSpec, train: Experiment) -> SystemSpec:
    """Every input delay to estimate with finite bounds: an unbounded ``tau_max`` becomes a
    quarter period of the training output's band edge (:mod:`cvxid.model.input_delay`)."""
    if all(s.input_delay is None or np.isfinite(s.input_delay.tau_max) for s in system.equations.values()):
        return system
    bound = record_bound([train.output(s.coordinate) for s in system.equations.values()], train.dt)
    return replace(system, equations={label: replace(s, input_delay=s.input_delay.resolved(bound))
                                      if s.input_delay is not None else s for label, s in system.equations.items()})


def _check_input_delay(system: SystemSpec, experiments: list[Experiment]) -> None:
    """An input delay longer than half the shortest record leaves most of it driven by the
    held first sample: refused, naming the key."""
    limit = 0.5 * min(e.duration for e in experiments)
    for spec in system.equations.values():
        late = spec.input_delay
        if late is None:
            continue
        key, value = ("[model] input_delay", late.value) if not late.free else ("[model.input_delay] tau_max",
                                                                                 late.tau_max)
        if value > limit:
            raise CvxidError(f"{key} = {value:.4g} s is more than half the shortest record ({2 * limit:g} s): "
                             "the model would read the held first sample of the input for most of it; give a "
                             "smaller delay or longer records")


def _estimate_input_delay(system: SystemSpec, rows: SystemBuilder, tau: float | None, solver: str):
    """The input's delay by the equation-error profile of the whole library at the
    fed-back delay ``tau`` (:func:`~cvxid.identify.profile.profile_input_delay`); the
    system at that delay and the profile."""
    profile = profile_input_delay(rows, system.equations, tau, nonnegative=system.nonnegative, ties=system.ties)
    return replace(system, equations=with_input_tau(system.equations, profile.estimate)), profile


def _compare(out: RunResult):
    """The final model against the test experiment, once, every coordinate
    (:func:`~cvxid.diagnosis.compare.compare_system`): free-run and k-step-ahead fit; a
    diverging simulation is a warning of the run.  And a polished model against the
    training experiment it was fitted on (``out.train_comparisons``), from the initial
    state the output-error polish estimated where it fitted that record whole (else
    estimated again): what the gap warning reads beside the test record
    (:func:`_warn_incomplete`)."""
    if out.polish is not None:
        start = _polished_start(out)
        compared = compare_system(out.system, out.train, given=start)
        if start is not None and not _reproduces(compared, out.polish):
            start, compared = None, compare_system(out.system, out.train)
        out.train_comparisons = compared if start is None else {
            c: replace(m, initial="the polish's") for c, m in compared.items()}
    if out.test is None:
        return
    out.comparisons = compare_system(out.system, out.test)
    for message in dict.fromkeys(c.message for c in out.comparisons.values() if c.message):
        warnings.warn(message, CvxidWarning, stacklevel=2)


SAME_RUN = 1e-6
"""The relative difference between the training free run's RMS from the polish's start and
the polish's own simulation RMS within which the two are the same simulation
(:func:`_reproduces`; measured by a review: 1.2e-10 at most over 42 runs)."""


def _reproduces(compared: dict, polish) -> bool:
    """Whether the training free run of one equation from the polish's start is the
    polish's own simulation (its RMS within :data:`SAME_RUN`); a coupled system's RMS
    mixes its coordinates' and is taken as given."""
    if len(compared) != 1:
        return True
    rms = next(iter(compared.values())).rms
    return rms is not None and abs(rms / polish.rms_after - 1.0) <= SAME_RUN


def _polished_start(out: RunResult) -> dict | None:
    """The training record's initial state (coordinate → (position, velocity)) the final
    output-error polish estimated, when it fitted that record as one stretch (the state is
    then the free run's own least-squares start: :func:`_reproduces` checks one equation's
    model against the polish's simulation, a coupled system must be the polish's own);
    else None."""
    polish = out.polish
    if len(polish.initial) != 1 or out.train.gaps or out.coupled and polish.system is not out.system:
        return None
    return polish.initial[0]


def _diagnose(spec, out: RunResult, rows: SystemBuilder, test_rows: SystemBuilder | None, velocity: str):
    """Diagnose → add → refit (:func:`~cvxid.diagnosis.refine.refine`, the same loop for
    every :math:`N`), on the run's own transformed data; the library is selected anew beside
    each added effect by the run's own selection.  Returns the train and test data's
    builders of the refined system (new ones when a fed-back delay was added)."""
    settings, fit = spec.diagnose, spec.fit
    steps = settings.max_steps if settings.refine else 0
    selection = Selection(fit.estimator, fit.lambdas, fit.selection, fit.stability) \
        if fit.estimator in SELECTING else None
    out.refinement = refine(out.system, out.train, out.test, settings.candidates, steps, velocity, rows.window,
                            builders=(rows, test_rows), selection=selection)
    out.refinement.ranking_only = not settings.refine
    system = out.refinement.system
    out.diagnosis = out.refinement.diagnoses[0] if out.refinement.diagnoses else diagnose(
        system, out.train, out.test, settings.candidates, velocity, rows.window, builders=(rows, test_rows))
    rows, test_rows = out.refinement.builders
    if out.refinement.steps and system.spec.exact:
        out.tau = dict(out.tau or {}, estimate=system.tau, interval=system.info.get("tau_interval"),
                       method="profile (after refinement)")
    late = [s.input_delay for s in system.specs.values() if s.input_delay is not None and s.input_delay.free]
    if out.refinement.steps and late:
        out.input_delay = {"estimate": late[0].value, "interval": None, "method": "profile (after refinement)"}
    out.system = system
    out.problem = Problem.from_regression(rows.at(system.tau, system.specs), system.spec.nonnegative,
                                          spec.fit.solver, ties=system.ties)
    return rows, test_rows


COUPLED_POLISH = dict(coarse_step=4e-3, max_iterations=100, grid=0, final_iterations=10)
"""A coupled system's polish schedule (the run's, the stepwise search's and the pruning's):
one start, a coarser first step, no delay profile (a coupled record is long and every
coordinate is simulated; on the flexible joint the default schedule took 32 s, this one 2)."""


def _schedule(system: SystemSpec) -> dict:
    """The output-error polish's settings for ``system``: :data:`COUPLED_POLISH` for
    several equations, the defaults for one."""
    return COUPLED_POLISH if system.single is None else {}


def _polish(out: RunResult, rows: SystemBuilder):
    """The output-error polish of every coordinate (``rows``: the equation-error
    regression of ``out.system``, for the pruning's additions); its delay interval replaces the
    profile's.  With ``[diagnose] refine`` and a test record, then the diagnosis by
    simulation error (:mod:`cvxid.diagnosis.simulation`)."""
    out.unpolished = out.system
    out.polish = polish(out.system, out.train, **_schedule(out.system.spec))
    _prune(out, rows)
    settings = out.spec.diagnose
    if settings is not None and settings.refine and settings.simulation and out.test is not None:
        out.simulation_refinement = refine_by_simulation(out.polish, out.train, out.test, settings.candidates,
                                                         settings.max_steps, _schedule(out.system.spec),
                                                         out.spec.fit.n_jobs)
        out.polish = out.simulation_refinement.polish
    out.system = out.polish.system
    _delays_of_polish(out)
    _warn_added_then_zero(out)


def _warn_added_then_zero(out: RunResult) -> None:
    """An effect the diagnosis added that the output-error polish set to 0 (held at its
    sign constraint's bound): the refinement table lists it, the final model lacks it, and
    the run says why."""
    if out.refinement is None:
        return
    zero = [column for step in zeroed(out.refinement.steps, out.polish.system.coefficients) for column in step.columns]
    if zero:
        it = "it" if len(zero) == 1 else "them"
        warnings.warn(
            f"the diagnosis added {', '.join(zero)}, and the output-error polish set {it} to 0 (at the sign "
            f"constraint's bound): the simulation error does not want {it}, so the final model leaves {it} out",
            CvxidWarning, stacklevel=2)


def _prune(out: RunResult, rows: SystemBuilder) -> None:
    r"""``[fit] prune``: the terms the selector chose from the library, pruned by simulation
    error after the polish, and exchanged for the library's other terms while the model
    misses the training record by more than its noise
    (:func:`~cvxid.identify.stepwise.prune_by_simulation`).  Listed
    terms are never pruned, nor the effects the diagnosis added (its rule already asked the
    test record's errors), nor the linear ``x`` and ``x'``: a delay stands in for a damping
    in the simulation error (:math:`b\,x(t-\tau) \approx b\,x - b\,\tau\,\dot x`), so
    only the equation's selection may drop them."""
    if not out.spec.fit.prune or out.spec.fit.estimator not in SELECTING:
        return
    system = out.polish.system
    added = {c for step in out.refinement.steps for c in step.columns} if out.refinement is not None else set()
    removable = [system.column(label, n) for label, spec in system.specs.items() for n in spec.library.names
                 if n not in spec.listed and n not in spec.linear_terms and system.column(label, n) not in added]
    if removable:
        out.pruning = prune_by_simulation(out.polish, out.train, removable, rows, schedule=_schedule(out.system.spec))
        out.polish = out.pruning.polish


def _delays_of_polish(out: RunResult) -> None:
    """The fed-back and the input's delays (estimate, 95 % interval) of ``out.polish``, when
    it fitted them, in place of the earlier stages'."""
    for name, attribute in (("tau", "tau"), ("tau_u", "input_delay")):
        if name in out.polish.parameters:
            setattr(out, attribute, {"estimate": out.polish.parameters[name],
                                     "interval": list(out.polish.interval(name)), "method": "output_error"})


def _score(out: RunResult, test_rows: SystemBuilder | None):
    """The test experiment's equation error of the final coefficients."""
    if test_rows is None:
        return
    validation = test_rows.at(out.system.tau, out.system.specs)
    coefficients = out.system.coefficients
    vector = np.array([coefficients.get(n, 0.0) for n in validation.names])
    out.test_mse, out.test_nmse = validation.mse(vector), validation.nmse(vector)


def _stepwise(spec: ProblemSpec, system: SystemSpec, rows: SystemBuilder, test_rows: SystemBuilder | None,
              train: Experiment, test: Experiment | None) -> RunResult:
    """``estimator = "stepwise_oe"``: terms chosen by simulation error
    (:mod:`cvxid.identify.stepwise`), then the delay profiled on them and every parameter
    polished at the sample step; the delay's interval is the profile's."""
    search = stepwise_output_error(system, rows, train, schedule=_schedule(system))
    system = search.system
    problem = Problem.from_regression(rows.at(system.tau, system.specs), system.spec.nonnegative, spec.fit.solver,
                                      ties=system.ties)
    out = RunResult(spec, system, None, problem, train, test, float("nan"), float("nan"), stepwise=search,
                    window=rows.window)
    out.polish = search.final
    _delays_of_polish(out)
    _score(out, test_rows)
    return out


def order_search(spec: ProblemSpec, orders=range(1, 7), samples: int | None = None, fraction: float = 0.5,
                 seed: int = 0, n_jobs: int = 1, train: Regression | None = None, test: Regression | None = None,
                 show_progress: bool = True, boot: BootstrapSettings | None = None) -> OrderSearch:
    """The paper's Algorithm 1 on ``spec``'s polynomial library: every order in ``orders``
    scored on the test experiment, with its fit settings; ``samples`` bootstraps per order
    (none: a single path each), or ``boot`` settings.  ``train``/``test`` regressions at
    the highest order may be passed to skip building them; built here, an exact delay's
    are at the delay profiled on the training record (every term of the highest order)."""
    if "test" not in spec.data and test is None:
        raise CvxidError("the order search scores orders on the test experiment: add [data.test]")
    fit = spec.fit
    orders = sorted({int(o) for o in orders})
    top = spec.at_order(spec.system, orders[-1])
    velocity = fit.velocity if fit.velocity in ESTIMATORS else "measured"
    if train is None or test is None:
        rows = SystemBuilder(top.equations, spec.experiment("train"), velocity, fit.window, fit.allow_large)
        tau = fit_support(top, rows, solver=fit.solver).tau if top.exact else None
        train = train if train is not None else rows.at(tau)
        if test is None:
            record = spec.experiment("test")
            test = SystemBuilder(top.equations, record, velocity,
                                 windows_for_test(fit.window, rows.window, top.equations.values(), record),
                                 fit.allow_large).at(tau)
    if boot is None and samples:
        boot = BootstrapSettings(samples, fraction, seed, n_jobs)
    return search_orders(lambda order: spec.at_order(top, order), train, test, orders, fit.lambdas,
                         fit.estimator, fit.debias, fit.selection, fit.solver, boot, show_progress)


def refine_spec(spec: ProblemSpec | str | FilePath, **settings):
    """Run ``spec`` with its diagnosis loop on (``[diagnose] refine = true``); the loop's
    :class:`~cvxid.diagnosis.refine.Refinement` (steps, diagnoses, final model, ``plot()``)."""
    from cvxid.spec.problem import DiagnoseSettings

    if not isinstance(spec, ProblemSpec):
        spec = load_problem(spec)
    if "test" not in spec.data:
        raise CvxidError("the diagnosis compares the models on a test record: add [data.test] to the spec")
    current = spec.diagnose or DiagnoseSettings()
    spec = replace(spec, diagnose=replace(current, refine=True, **settings))
    return run(spec).refinement
